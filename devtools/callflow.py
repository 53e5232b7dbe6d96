"""How often a program's calls alternate between two of its modules.

    python -m devtools.callflow --between backend.fit.search backend.fit.objective \\
        [--within backend.fit.pipeline.fit] [--root backend] [--depth N] [--among backend.fit] [--sites N] \\
        [--save FILE | --load FILE] [--module backend] -- fit --example --out DIR ...

runs ``python -m MODULE ARGS`` (``backend`` by default) under a trace hook and records, in order,
each call and each return that crosses from one module under ``--root`` to another: the module of a
frame is its globals' ``__name__`` (a callback belongs to the module that defines it), and frames
outside ``--root`` (torch, numpy, the standard library) are transparent, so a crossing is between a
frame and the nearest ``--root`` frame below it on its thread's stack. ``--within`` counts only
what happens while that function (module.qualified_name) runs, e.g. a fit without its output
renders. ``--depth N`` counts modules by their first N dotted names (``--depth 2``: ``backend.fit``
against ``backend.texture``); a ``--between`` name stands for itself and every module below it.

The measure, for two modules A and B::

    alternations(A, B) = the calls from A into B or from B into A made after control has come back
                         across that boundary (a return from B to A, or from A to B) at least once

so data that goes down once (A calls B, B returns its values to A) alternates 0 times, and every
further call across counts one: A calling B in a loop of n times, n - 1; B calling A back n times
from one call, n - 1. The report also counts the callbacks: calls into a module already on the
stack below the caller (A -> B -> A), which a loop of calls from A into B never makes: data going
back up. Calls within a module, or through a third module (A -> C -> B), are not crossings of
A and B. The counts depend on the run (its settings, its data), so compare runs of one command.

It prints the calls each way and the alternations for ``--between``, the call sites (caller ->
callee function) that cross most, and the module pairs (under ``--among``) that alternate most;
``--save`` keeps the crossings, which ``--load`` reports again (other pairs, other groupings)
without running. The hook is
:func:`sys.settrace` with line events off (a call and a return event per Python frame), not
:func:`sys.setprofile`, which also reports every call into C (each torch operation) and makes a fit
many times slower. Run short fits; ``WFC_COMPILE=0`` keeps torch.compile out of the count.
"""
from __future__ import annotations

import argparse
import functools
import json
import runpy
import sys
import threading
from collections import Counter
from contextlib import contextmanager
from dataclasses import dataclass, field


@dataclass(frozen=True)
class Crossing:
    """A call (``kind`` "call") from ``caller`` into ``callee``, or the return (``kind`` "return")
    from ``callee`` back to ``caller``: (module, function) each."""

    kind: str
    caller: tuple[str, str]
    callee: tuple[str, str]


@dataclass
class CallFlow:
    """The crossings between modules under ``root``, in the order they happened (per thread), while
    ``within`` (module.qualified_name; None: always) runs."""

    root: str
    within: str | None = None
    crossings: dict[int, list[Crossing]] = field(default_factory=dict)
    _stacks: dict[int, list] = field(default_factory=dict)
    _inside: dict[int, int] = field(default_factory=dict)  # per thread, ``within`` frames on its stack

    def _record(self, thread: int, kind: str, caller: tuple[str, str], callee: tuple[str, str]) -> None:
        if self.within is None or self._inside.get(thread):
            self.crossings.setdefault(thread, []).append(Crossing(kind, caller, callee))

    def trace(self, frame, event, arg):
        """The :func:`sys.settrace` hook: on each call, a ``root`` frame goes on its thread's stack
        (and gets :meth:`_returned` for its return, with its line events off), a crossing where the
        module changes."""
        module = frame.f_globals.get("__name__")
        if event != "call" or module is None or not under(module, self.root):
            return None
        thread = threading.get_ident()
        stack = self._stacks.setdefault(thread, [])
        here = (module, frame.f_code.co_qualname)
        entering = self.within is not None and f"{module}.{here[1]}" == self.within
        self._inside[thread] = self._inside.get(thread, 0) + entering
        if stack and stack[-1][0] != module:
            self._record(thread, "call", stack[-1], here)
        stack.append(here)
        frame.f_trace_lines = False
        return self._returned

    def _returned(self, frame, event, arg):
        if event != "return":
            return self._returned
        thread = threading.get_ident()
        stack = self._stacks[thread]
        here = stack.pop()
        if stack and stack[-1][0] != here[0]:
            self._record(thread, "return", stack[-1], here)
        if self.within is not None and f"{here[0]}.{here[1]}" == self.within:
            self._inside[thread] -= 1
        return None

    @contextmanager
    def tracing(self):
        """The hook on this thread and the threads started meanwhile."""
        threading.settrace(self.trace)
        sys.settrace(self.trace)
        try:
            yield self
        finally:
            sys.settrace(None)
            threading.settrace(None)

    def run(self, module: str, args: list[str]) -> int:
        """Runs ``python -m module args`` under the hook; its exit code."""
        sys.argv = [module, *args]
        with self.tracing():
            try:
                runpy.run_module(module, run_name="__main__", alter_sys=True)
            except SystemExit as stop:
                return stop.code if isinstance(stop.code, int) else (0 if stop.code is None else 1)
        return 0


def under(module: str, package: str) -> bool:
    """Whether ``module`` is ``package`` or lies below it."""
    return module == package or module.startswith(package + ".")


def grouped(module: str, names: tuple[str, ...], depth: int | None) -> str:
    """The name ``module`` is counted under: the first of ``names`` it is or lies below, else its
    first ``depth`` dotted names (all of them without a depth)."""
    for name in names:
        if under(module, name):
            return name
    return ".".join(module.split(".")[:depth]) if depth else module


def alternations(crossings: list[Crossing], a: str, b: str, group) -> tuple[int, int, int]:
    """(calls from ``a`` into ``b``, calls from ``b`` into ``a``, alternations: the calls across
    made after a return across; module docstring) of one thread's crossings, modules named by
    ``group(module)``."""
    into_b = into_a = alternating = 0
    returned = False
    for crossing in crossings:
        pair = (group(crossing.caller[0]), group(crossing.callee[0]))
        if pair not in ((a, b), (b, a)):
            continue
        if crossing.kind == "return":
            returned = True
            continue
        into_b += pair == (a, b)
        into_a += pair == (b, a)
        alternating += returned
    return into_b, into_a, alternating


def callbacks(crossings: list[Crossing], group) -> Counter:
    """(module called back, the module calling it) -> calls, of one thread's crossings: calls into a
    module that is already on the stack below the caller (``A -> B -> A``: a callback, or data
    going back up), as ``group(module)`` names them. A pipeline whose data goes down once has none;
    a loop of calls from A into B has none either (B returns before A calls again)."""
    stack, counts = [], Counter()
    for crossing in crossings:
        caller, callee = group(crossing.caller[0]), group(crossing.callee[0])
        if crossing.kind == "return":
            if stack:
                stack.pop()
            continue
        if not stack:
            stack.append(caller)
        if caller != callee and callee in stack[:-1]:
            counts[(callee, caller)] += 1
        stack.append(callee)
    return counts


def save(flow: CallFlow, path: str) -> None:
    """The crossings as JSON lines (thread, kind, caller module, caller function, callee module, callee
    function), for :func:`load`."""
    with open(path, "w") as out:
        for thread, crossings in flow.crossings.items():
            for c in crossings:
                out.write(json.dumps([thread, c.kind, *c.caller, *c.callee]) + "\n")


def load(path: str, root: str) -> CallFlow:
    """A flow :func:`save` wrote."""
    flow = CallFlow(root)
    with open(path) as lines:
        for line in lines:
            thread, kind, *names = json.loads(line)
            flow.crossings.setdefault(thread, []).append(Crossing(kind, tuple(names[:2]), tuple(names[2:])))
    return flow


def pair_alternations(crossings: list[Crossing], group) -> Counter:
    """:func:`alternations` of every pair of modules (sorted names, as ``group(module)`` names them)
    in one pass over one thread's crossings."""
    returned, counts = set(), Counter()
    for crossing in crossings:
        pair = tuple(sorted((group(crossing.caller[0]), group(crossing.callee[0]))))
        if pair[0] == pair[1]:
            continue
        if crossing.kind == "return":
            returned.add(pair)
        elif pair in returned:
            counts[pair] += 1
    return counts


def report(flow: CallFlow, between: tuple[str, str] | None, depth: int | None, sites: int,
           among: str | None = None) -> str:
    """The counts for ``between``, the call sites that cross it most, the pairs (of modules under
    ``among``, if given) that alternate most."""
    names = between or ()

    @functools.cache
    def group(module):
        return grouped(module, names, depth)

    threads = list(flow.crossings.values())
    lines = _between_lines(threads, between, group, sites) if between else []
    pairs = sum((pair_alternations(crossings, group) for crossings in threads), Counter())
    if among is not None:
        pairs = Counter({pair: count for pair, count in pairs.items() if all(under(m, among) for m in pair)})
    lines.append("module pairs that alternate most (alternations):")
    lines += [f"  {first} <-> {second}: {count}" for (first, second), count in pairs.most_common(sites) if count]
    return "\n".join(lines + _callback_lines(threads, group, among, sites))


def _callback_lines(threads: list[list[Crossing]], group, among: str | None, sites: int) -> list[str]:
    """The callbacks' count and the pairs (calling module -> module called back) that make most."""
    back = sum((callbacks(crossings, group) for crossings in threads), Counter())
    if among is not None:
        back = Counter({pair: count for pair, count in back.items() if all(under(m, among) for m in pair)})
    return [f"calls back into a module below on the stack (callbacks): {sum(back.values())}",
            *(f"  {caller} -> {callee}: {count}" for (callee, caller), count in back.most_common(sites))]


def _between_lines(threads: list[list[Crossing]], between: tuple[str, str], group, sites: int) -> list[str]:
    """The calls each way and the alternations between the two modules, and the call sites across."""
    a, b = between
    counts = [alternations(crossings, a, b, group) for crossings in threads]
    into_b, into_a, alternating = (sum(count[k] for count in counts) for k in range(3))
    where = Counter((c.caller, c.callee) for crossings in threads for c in crossings
                    if c.kind == "call" and {group(c.caller[0]), group(c.callee[0])} == {a, b})
    return [f"{a} -> {b}: {into_b} calls", f"{b} -> {a}: {into_a} calls", f"alternations({a}, {b}): {alternating}",
            "call sites across it (caller -> callee: calls):",
            *(f"  {m}.{f} -> {n}.{g}: {count}" for ((m, f), (n, g)), count in where.most_common(sites))]


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devtools.callflow", description=__doc__.split("\n\n")[0])
    parser.add_argument("--between", nargs=2, metavar=("A", "B"), help="two modules (or packages) to count")
    parser.add_argument("--within", help="count only while this function runs (module.qualified_name)")
    parser.add_argument("--root", default="backend", help="the package whose modules are counted (default backend)")
    parser.add_argument("--depth", type=int, default=None, help="count modules by their first N dotted names")
    parser.add_argument("--sites", type=int, default=12, help="lines of each table (default 12)")
    parser.add_argument("--module", default="backend", help="the module to run with python -m (default backend)")
    parser.add_argument("--among", help="list only the pairs of modules under this package")
    parser.add_argument("--save", metavar="FILE", help="also write the crossings to FILE (JSON lines)")
    parser.add_argument("--load", metavar="FILE", help="report the crossings a --save wrote instead of running")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="-- then the module's arguments")
    options = parser.parse_args(argv)
    args = options.args[1:] if options.args[:1] == ["--"] else options.args
    code = 0
    if options.load:
        flow = load(options.load, options.root)
    else:
        flow = CallFlow(options.root, options.within)
        code = flow.run(options.module, args)
    if options.save:
        save(flow, options.save)
    print(report(flow, tuple(options.between) if options.between else None, options.depth, options.sites,
                 options.among))
    return code


if __name__ == "__main__":
    sys.exit(main())
