"""The call-flow measure (devtools/callflow.py): alternations between two modules."""
import threading
import types

from devtools.callflow import CallFlow, alternations, grouped


def module(name, source):
    made = types.ModuleType(name)
    exec(compile(source, f"<{name}>", "exec"), made.__dict__)
    return made


OBJECTIVE = module("pkg.objective", "def value(k):\n    return 2 * k\n\n"
                                    "def values(ks):\n    return [value(k) for k in ks]\n\n"
                                    "def each(ks, callback):\n    for k in ks:\n        callback(value(k))\n")
SEARCH = module("pkg.search", "def looped(objective, ks):\n    return min(objective.value(k) for k in ks)\n\n"
                              "def once(objective, ks):\n    return min(objective.values(ks))\n\n"
                              "def called_back(objective, ks):\n    seen = []\n"
                              "    objective.each(ks, seen.append)\n    objective.each(ks, note)\n    return seen\n\n"
                              "def note(value):\n    return value\n")


def counted(call, *args):
    flow = CallFlow("pkg")
    with flow.tracing():
        call(*args)
    crossings = flow.crossings.get(threading.get_ident(), [])
    return alternations(crossings, "pkg.search", "pkg.objective", lambda m: grouped(m, (), None))


def test_a_loop_of_calls_alternates_once_less_than_it_calls_and_values_down_not_at_all():
    assert counted(SEARCH.looped, OBJECTIVE, range(5)) == (5, 0, 4)
    assert counted(SEARCH.once, OBJECTIVE, range(5)) == (1, 0, 0)       # the comprehension stays in objective


def test_callbacks_alternate_and_builtins_are_transparent():
    # seen.append is C: no crossing; note is search's own function, called back 3 times from objective
    assert counted(SEARCH.called_back, OBJECTIVE, range(3)) == (2, 3, 4)


def test_modules_are_grouped_by_a_named_package_or_by_depth():
    assert grouped("backend.fit.search", ("backend.fit",), None) == "backend.fit"
    assert grouped("backend.texture.lattice", ("backend.fit",), 2) == "backend.texture"
    assert grouped("backend.texture.lattice", (), None) == "backend.texture.lattice"


def test_saved_crossings_report_as_the_run_did(tmp_path):
    from devtools.callflow import load, report, save
    flow = CallFlow("pkg")
    with flow.tracing():
        SEARCH.called_back(OBJECTIVE, range(3))
    save(flow, tmp_path / "flow.jsonl")
    again = load(tmp_path / "flow.jsonl", "pkg")
    assert again.crossings == flow.crossings
    assert report(again, ("pkg.search", "pkg.objective"), None, 5) == report(flow, ("pkg.search", "pkg.objective"),
                                                                             None, 5)


def test_every_pair_in_one_pass_counts_as_the_pair_alone():
    from devtools.callflow import pair_alternations
    flow = CallFlow("pkg")
    with flow.tracing():
        SEARCH.looped(OBJECTIVE, range(4))
        SEARCH.called_back(OBJECTIVE, range(3))
    crossings = flow.crossings[threading.get_ident()]
    alone = alternations(crossings, "pkg.search", "pkg.objective", lambda m: m)
    assert pair_alternations(crossings, lambda m: m) == {("pkg.objective", "pkg.search"): alone[2]}


def test_callbacks_count_calls_back_into_a_module_below_and_not_a_loop_of_calls_down():
    from devtools.callflow import callbacks
    flow = CallFlow("pkg")
    with flow.tracing():
        SEARCH.looped(OBJECTIVE, range(4))     # down four times, never back
        SEARCH.called_back(OBJECTIVE, range(3))  # objective calls search's note back three times
    crossings = flow.crossings[threading.get_ident()]
    assert callbacks(crossings, lambda m: m) == {("pkg.search", "pkg.objective"): 3}
