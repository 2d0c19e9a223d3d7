"""Spot's translations in a child process, under a time budget.

Spot builds a deterministic automaton by way of constructions that can grow
exponentially: ``always (a -> X[30] b)`` must remember the last 30 values of a
(2^30 states), and ``always (a -> F[0..50] b)``, whose monitor has 51 states,
goes through intermediate automata that double with each step of the bound.
Spot's Python bindings hold the GIL the whole time, so a handler that built such a
monitor in its own process would stop everything else, taking no message and
answering no request, for as long as Spot runs: minutes, or for ever.

So the translations run in one child process, forked at the first one (it
inherits Spot and the code, nothing to import), and the caller waits for the
answer at most :data:`budget` seconds, the GIL free meanwhile. Past it, the child
is killed (the next call forks a new one) and :class:`BudgetExceeded` raised: the
monitor is refused with a message that says why. Answers are cached here by the
call, so asking again costs nothing. Where fork is not available, the call runs in
this process, unbounded.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import multiprocessing
import resource
import signal
import threading
from collections import OrderedDict
from collections.abc import Callable, Hashable
from multiprocessing.connection import Connection
from typing import Any, TypeVar

T = TypeVar("T")

DEFAULT_BUDGET = 10.0  # seconds; `edgerv check` and `edgerv handler` take --synthesis-budget
CACHED = 4096  # answers kept


class BudgetExceeded(Exception):
    """Spot did not answer within the budget."""

    def __init__(self, seconds: float) -> None:
        super().__init__(seconds)
        self.seconds = seconds

    def __str__(self) -> str:
        return (
            f"building this monitor's automaton took more than {self.seconds:g} s: counted "
            "steps grow it exponentially (X[30] remembers 2^30 letters; F[0..50] goes through "
            "automata that double with each step)"
        )

    hint = (
        "write the bound as a duration (F[0..500ms], U[0..1s]: a clock, not a bigger "
        "automaton), split the assertion, or give more time with --synthesis-budget"
    )


class SpotDied(BudgetExceeded):
    """Spot's child process died building the automaton (a formula too deep for its
    recursion, or memory): the monitor is refused, as one over budget is."""

    def __str__(self) -> str:
        return (
            "Spot's process died building this monitor's automaton: the assertion is too "
            "deep or too large for it"
        )

    hint = "split the assertion into several monitors, each less deeply nested"


class SpotOutOfMemory(BudgetExceeded):
    """Spot asked for more than :data:`MEMORY` in its child process (its parser's error
    recovery takes gigabytes on a few characters: ``F F F []``)."""

    def __str__(self) -> str:
        return f"Spot needed more than {MEMORY >> 30} GiB for this assertion"

    hint = "check the assertion's syntax, or split it into several monitors"


MEMORY = 2 << 30  # bytes of address space Spot's child process may take beyond its own


def _serve(conn: Connection, parents: Connection) -> None:
    """The child: answer calls until the pipe closes (the parent's end, inherited, is
    closed here: else the child would hold it open and never see the parent go)."""
    parents.close()
    # Forked from a process whose asyncio loop handles signals (the operator under Kopf,
    # the handler's API), the child inherits that loop's no-op handler and wakeup fd: it
    # would ignore SIGTERM (multiprocessing terminates daemon children at exit, then
    # waits for them: the parent never exits) and a signal here would wake the parent.
    signal.set_wakeup_fd(-1)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    _limit_memory()
    while True:
        try:
            fn, args = conn.recv()
        except (EOFError, OSError):
            return
        try:
            conn.send((True, fn(*args)))
        except Exception as exc:  # sent back and raised there, as if called in place
            try:
                conn.send((False, exc))
            except Exception:  # an exception that does not pickle: its text
                conn.send((False, RuntimeError(f"{type(exc).__name__}: {exc}")))


def _limit_memory() -> None:
    """The child's address space: what it has at the fork plus :data:`MEMORY` (a bigger
    request raises MemoryError there, sent back like any exception)."""
    with contextlib.suppress(OSError, ValueError):
        with open("/proc/self/statm") as f:
            pages = int(f.read().split()[0])
        limit = pages * resource.getpagesize() + MEMORY
        _, hard = resource.getrlimit(resource.RLIMIT_AS)
        if hard == resource.RLIM_INFINITY or hard > limit:
            resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


def add_budget_argument(parser: argparse.ArgumentParser) -> None:
    """``--synthesis-budget SECONDS`` (for the commands that build monitors)."""
    parser.add_argument(
        "--synthesis-budget",
        type=_seconds,
        default=DEFAULT_BUDGET,
        metavar="SECONDS",
        help="give up building a monitor's automaton after this long and refuse the monitor "
        f"(default {DEFAULT_BUDGET:g}; Spot's work runs in a child process meanwhile)",
    )


def _seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not 0 < value < math.inf:
        raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds above 0")
    return value


class SpotWorker:
    """The child process and the answers it gave. Thread-safe: one call at a time."""

    def __init__(self, budget: float = DEFAULT_BUDGET) -> None:
        self.budget = budget
        self._lock = threading.Lock()
        self._conn: Connection | None = None
        self._child: Any = None
        self._answers: OrderedDict[Hashable, Any] = OrderedDict()

    def call(self, fn: Callable[..., T], *args: Hashable) -> T:
        """``fn(*args)`` (a module-level function of plain values), in the child."""
        key = (fn.__module__, fn.__qualname__, args)
        with self._lock:
            if key in self._answers:
                self._answers.move_to_end(key)
                return self._answers[key]  # type: ignore[no-any-return]
            value = self._call(fn, args)
            self._answers[key] = value
            if len(self._answers) > CACHED:
                self._answers.popitem(last=False)
            return value

    def _call(self, fn: Callable[..., T], args: tuple[Hashable, ...]) -> T:
        if "fork" not in multiprocessing.get_all_start_methods():
            return fn(*args)
        try:
            conn = self._start()
            conn.send((fn, args))
            if not conn.poll(self.budget):
                raise BudgetExceeded(self.budget)
            try:
                ok, value = conn.recv()
            except (EOFError, OSError):  # the child is gone: no answer will come
                raise SpotDied(self.budget) from None
        except BaseException:  # over budget, interrupted (a timer, Ctrl-C), the child died
            self.stop()  # its answer, if it ever comes, must not be taken for the next call
            raise
        if not ok:
            if isinstance(value, MemoryError):
                self.stop()  # a process that ran out may be in any state: a new one next
                raise SpotOutOfMemory(self.budget)
            raise value
        return value  # type: ignore[no-any-return]

    def _start(self) -> Connection:
        if self._conn is None or self._child is None or not self._child.is_alive():
            self.stop()
            ours, theirs = multiprocessing.get_context("fork").Pipe()
            child = multiprocessing.get_context("fork").Process(
                target=_serve, args=(theirs, ours), name="edgerv-spot", daemon=True
            )
            child.start()
            theirs.close()
            self._conn, self._child = ours, child
        return self._conn

    def stop(self) -> None:
        """Kill the child, if any (the next call forks a new one)."""
        if self._child is not None:
            self._child.kill()
            self._child.join()
        if self._conn is not None:
            self._conn.close()
        self._conn = self._child = None


worker = SpotWorker()  # the process's one child: Spot's state is per process anyway
