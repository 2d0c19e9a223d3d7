"""Spot's translations run in a child process under a time budget (core/spot_worker.py):
while Spot works, this process runs on; past the budget the child is killed and the
monitor refused; the next one is built by a new child."""

from __future__ import annotations

import contextlib
import threading
import time

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.language.spot_worker import BudgetExceeded, SpotWorker, worker
from edgerv.core.language.synthesis import _synthesize_cached
from kit.documents import compiled

SIGNALS = {"a": "bool", "b": "bool"}


def test_the_process_runs_on_while_spot_works_and_the_budget_ends_it() -> None:
    own = SpotWorker(budget=1.0)
    counted, stop = [0], threading.Event()

    def count() -> None:  # Python work beside Spot's: needs the GIL
        while not stop.is_set():
            counted[0] += 1
            time.sleep(0.001)

    thread = threading.Thread(target=count)
    thread.start()
    started = time.monotonic()
    try:
        with pytest.raises(BudgetExceeded):
            own.call(_synthesize_cached, "G(p0 -> X[30] p1)", "1", 2)
    finally:
        stop.set()
        thread.join()
    assert 1.0 <= time.monotonic() - started < 5.0
    assert counted[0] > 100  # about 1,000 in that second; 0 if Spot held the GIL here
    # the child was killed; the next call forks a new one and answers
    table = own.call(_synthesize_cached, "G(p0 -> p1)", "1", 2)
    assert table.live == 1
    own.stop()


def test_errors_come_back_as_they_were_raised_and_answers_are_kept() -> None:
    own = SpotWorker(budget=30.0)
    with pytest.raises(SyntaxError, match="missing closing parenthesis"):
        own.call(_synthesize_cached, "G(p0", "1", 2)
    first = own.call(_synthesize_cached, "G(p0 -> F p1)", "1", 2)
    own.stop()  # no child: a kept answer needs none
    assert own.call(_synthesize_cached, "G(p0 -> F p1)", "1", 2) is first


def test_a_monitor_over_budget_is_refused_at_its_assertion() -> None:
    before = worker.budget
    worker.budget = 0.5
    try:
        with pytest.raises(InputError) as info:
            compiled("always (a -> X[30] b)", SIGNALS)
    finally:
        worker.budget = before
    text = str(info.value)
    assert "test.yaml:6:" in text and "took more than 0.5 s" in text, text
    assert compiled("always (a -> X[3] b)", SIGNALS).table.live > 1  # the next one builds


EXITS = r"""
import asyncio, os, signal, sys
from edgerv.core.language.spot_worker import worker

async def main() -> None:
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    loop.add_signal_handler(signal.SIGTERM, stop.set)  # as Kopf's reactor does
    loop.add_signal_handler(signal.SIGUSR1, lambda: print("woken", flush=True))
    # a call forks the worker from an executor thread, as a sync Kopf handler does
    assert await loop.run_in_executor(None, worker.call, os.getpid) != os.getpid()
    print(worker._child.pid, flush=True)
    os.kill(worker._child.pid, signal.SIGUSR1)  # the child's signal must not wake us
    await asyncio.sleep(0.5)
    print("ready", flush=True)
    await stop.wait()

asyncio.run(main())
print("exiting", flush=True)  # then multiprocessing terminates and joins the child
"""


def test_a_process_with_an_event_loop_exits_though_it_forked_the_worker() -> None:
    """The operator's exit hung forever (found on the cluster: its pods took the whole
    grace period to go): the worker, forked from under Kopf's event loop, inherited the
    loop's signal handling and ignored the SIGTERM multiprocessing ends it with at exit."""
    import os
    import signal
    import subprocess
    import sys

    proc = subprocess.Popen(
        [sys.executable, "-c", EXITS], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    child = 0
    try:
        assert proc.stdout is not None
        child = int(proc.stdout.readline() or 0)
        assert proc.stdout.readline() == "ready\n"  # not "woken": the child's signal
        os.kill(proc.pid, signal.SIGTERM)
        out, err = proc.communicate(timeout=20)  # the worker ended: the pipes close
    finally:
        proc.kill()
        if child:
            with contextlib.suppress(ProcessLookupError):
                os.kill(child, signal.SIGKILL)  # else it would keep our pipes open
    assert proc.returncode == 0 and out == "exiting\n", (out, err)
