"""How often a program's calls alternate between two of its modules.

    python -m devtools.callflow --between backend.fit.search backend.fit.objective \\
        [--within backend.fit.pipeline.fit] [--root backend] [--depth N] [--sites N] [--module backend] \\
        -- fit --example --out DIR ...

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
from one call, n - 1. Calls within a module, or through a third module (A -> C -> B), are not crossings of
A and B. The counts depend on the run (its settings, its data), so compare runs of one command.

It prints the calls each way and the alternations for ``--between``, the call sites (caller ->
callee function) that cross most, and the module pairs that alternate most. The hook is
:func:`sys.settrace` with line events off (a call and a return event per Python frame), not
:func:`sys.setprofile`, which also reports every call into C (each torch operation) and makes a fit
many times slower. Run short fits; ``WFC_COMPILE=0`` keeps torch.compile out of the count.
"""
from __future__ import annotations

import argparse
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

    def _in_scope(self, module: str | None) -> bool:
        return module is not None and (module == self.root or module.startswith(self.root + "."))

    def _record(self, thread: int, kind: str, caller: tuple[str, str], callee: tuple[str, str]) -> None:
        if self.within is None or self._inside.get(thread):
            self.crossings.setdefault(thread, []).append(Crossing(kind, caller, callee))

    def trace(self, frame, event, arg):
        """The :func:`sys.settrace` hook: on each call, a ``root`` frame goes on its thread's stack
        (and gets :meth:`_returned` for its return, with its line events off), a crossing where the
        module changes."""
        module = frame.f_globals.get("__name__")
        if event != "call" or not self._in_scope(module):
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


def grouped(module: str, names: tuple[str, ...], depth: int | None) -> str:
    """The name ``module`` is counted under: the first of ``names`` it is or lies below, else its
    first ``depth`` dotted names (all of them without a depth)."""
    for name in names:
        if module == name or module.startswith(name + "."):
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


def report(flow: CallFlow, between: tuple[str, str] | None, depth: int | None, sites: int) -> str:
    """The counts for ``between``, the call sites that cross it most, the pairs that alternate most."""
    names = between or ()

    def group(module):
        return grouped(module, names, depth)

    threads = list(flow.crossings.values())
    lines = []
    if between:
        a, b = between
        counts = [alternations(crossings, a, b, group) for crossings in threads]
        into_b, into_a, alternating = (sum(count[k] for count in counts) for k in range(3))
        lines += [f"{a} -> {b}: {into_b} calls", f"{b} -> {a}: {into_a} calls",
                  f"alternations({a}, {b}): {alternating}"]
        where = Counter((c.caller, c.callee) for crossings in threads for c in crossings
                        if c.kind == "call" and {group(c.caller[0]), group(c.callee[0])} == {a, b})
        lines.append("call sites across it (caller -> callee: calls):")
        lines += [f"  {m}.{f} -> {n}.{g}: {count}" for ((m, f), (n, g)), count in where.most_common(sites)]
    modules = sorted({group(m) for crossings in threads for c in crossings for m in (c.caller[0], c.callee[0])})
    pairs = Counter({(first, second): sum(alternations(c, first, second, group)[2] for c in threads)
                     for k, first in enumerate(modules) for second in modules[k + 1:]})
    lines.append("module pairs that alternate most (alternations):")
    lines += [f"  {first} <-> {second}: {count}" for (first, second), count in pairs.most_common(sites) if count]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m devtools.callflow", description=__doc__.split("\n\n")[0])
    parser.add_argument("--between", nargs=2, metavar=("A", "B"), help="two modules (or packages) to count")
    parser.add_argument("--within", help="count only while this function runs (module.qualified_name)")
    parser.add_argument("--root", default="backend", help="the package whose modules are counted (default backend)")
    parser.add_argument("--depth", type=int, default=None, help="count modules by their first N dotted names")
    parser.add_argument("--sites", type=int, default=12, help="lines of each table (default 12)")
    parser.add_argument("--module", default="backend", help="the module to run with python -m (default backend)")
    parser.add_argument("args", nargs=argparse.REMAINDER, help="-- then the module's arguments")
    options = parser.parse_args(argv)
    args = options.args[1:] if options.args[:1] == ["--"] else options.args
    flow = CallFlow(options.root, options.within)
    code = flow.run(options.module, args)
    print(report(flow, tuple(options.between) if options.between else None, options.depth, options.sites))
    return code


if __name__ == "__main__":
    sys.exit(main())
