"""bench profile (devtools/bench/profile.py): a fit's time by stage, by torch pass and by function."""
import json
from pathlib import Path
from types import SimpleNamespace

import torch

from devtools.bench import profile


def event(name, parent=None, self_us=0.0):
    return SimpleNamespace(name=name, cpu_parent=parent, self_cpu_time_total=self_us)


def test_an_operator_is_backward_where_autograds_engine_ran_it_and_the_rest_is_forward():
    engine = event("autograd::engine::evaluate_function: MulBackward0")
    step = event("Optimizer.step#Adam.step")
    events = [event("aten::mul", None, 3e6), engine, event("aten::mul", event("aten::mul_x", engine), 2e6),
              event("aten::add", engine, 1e6), event("aten::lerp", step, 0.5e6), step]
    split = profile.operator_split(events, top=5)
    assert (split["forward_s"], split["backward_s"], split["step_s"]) == (3.0, 3.0, 0.5)
    assert split["top_backward"] == [["aten::mul", 2.0], ["aten::add", 1.0]]
    assert split["forward_share"] == round(3.0 / 6.5, 3)


def test_torchs_own_events_split_into_the_forward_and_the_backward_pass():
    x = torch.linspace(0.1, 1.0, 10_000, requires_grad=True)
    with torch.profiler.profile(activities=[torch.profiler.ProfilerActivity.CPU]) as prof:
        (torch.exp(x) * x).sum().backward()
    split = profile.operator_split(prof.events(), top=20)
    assert split["forward_s"] > 0 and split["backward_s"] > 0
    assert "aten::exp" in dict(split["top_forward"]) and "aten::exp" not in dict(split["top_backward"])
    assert "aten::mul" in dict(split["top_backward"])  # d(exp(x) x)/dx multiplies in the backward pass


def test_stages_are_the_fits_timings_without_their_overlaps_and_the_rest_of_the_command():
    timings = {"lattice_s": 2.0, "search_s": 5.0, "optimise_s": 10.0, "warp_s": 1.0, "total_s": 15.0}
    table = profile.stage_table(timings, wall_s=20.0)
    assert table["stages"] == {"lattice": [2.0, 0.1], "search": [3.0, 0.15], "optimise": [10.0, 0.5],
                               "rest": [5.0, 0.25]}
    assert table["warp_of_optimise_s"] == 1.0


def test_functions_are_named_by_their_module_under_the_package():
    assert profile._module_of("/x/y/backend/model/bsdf.py", "backend") == "backend.model.bsdf"
    assert profile._module_of("/x/backend/texture/placement/__init__.py", "backend") == "backend.texture.placement"
    assert profile._module_of("/usr/lib/python3.11/json/decoder.py", "backend") is None


def test_the_command_prints_and_records_each_section_of_a_profiled_fit(tmp_path, monkeypatch, capsys):
    from devtools.cli.main import main

    def fit(argv):  # a stand-in fit: some torch work with gradients, and the timings a fit writes
        out = Path(argv[argv.index("--out") + 1])
        out.mkdir(parents=True)
        x = torch.ones(1000, requires_grad=True)
        (x * x).sum().backward()
        (out / "metrics.json").write_text(json.dumps({"timings": {"lattice_s": 0.1, "search_s": 0.2,
                                                                  "optimise_s": 0.3, "total_s": 0.5}}))
        return 0

    monkeypatch.setattr(profile, "backend_main", fit)
    assert main(["bench", "profile", "--iterations", "2", "--json", "--no-record", "--operators"]) == 0
    printed = [json.loads(line) for line in capsys.readouterr().out.splitlines() if line.startswith("{")]
    assert [row.get("section", row.get("summary")) for row in printed] == ["stages", "passes", "functions",
                                                                           "operators", "profile"]
    assert printed[1]["backward_s"] > 0 and printed[1]["step_s"] == 0.0  # a backward pass, no optimiser
    assert printed[3]["backward_s"] > 0 and printed[-1]["fit"] == ["fit", "--example", "--iterations", "2"]
    assert torch.autograd.backward is original_backward  # the hooks are gone afterwards


original_backward = torch.autograd.backward


def test_a_timed_call_adds_its_wall_time_once_even_when_it_calls_itself():
    seconds = {"backward": 0.0}
    calls = []

    class Owner:
        @staticmethod
        def work(n):
            calls.append(n)
            return Owner.work(n - 1) if n else 0

    with profile.timed(Owner, "work", seconds, "backward"):
        Owner.work(3)
    assert calls == [3, 2, 1, 0] and 0 < seconds["backward"] < 1.0  # one outer call's time, not four
    assert Owner.work.__name__ == "work" and not hasattr(Owner.work, "__wrapped__")
