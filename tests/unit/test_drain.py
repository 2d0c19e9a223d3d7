"""``edgerv handler --drain``: after SIGTERM the handler runs on until no monitor is active
on it (the operator moves them away), at most the drain's seconds; a second signal ends
the wait. (The process and its pod: tests/e2e, a handler pod going away.)"""

from __future__ import annotations

import argparse
import threading
import time

import pytest

from edgerv.handler.engine import Engine
from edgerv.handler.main import add_arguments, drain
from kit.documents import compiled


def engine_with(active: bool) -> Engine:
    e = Engine("edge")
    e.put(compiled("always (x < 5)", {"x": "float"}), active=active)
    return e


def test_nothing_active_ends_the_drain_at_once() -> None:
    started = time.monotonic()
    drain(engine_with(active=False), 30.0, threading.Event())
    assert time.monotonic() - started < 1.0


def test_the_drain_waits_until_the_monitors_are_gone() -> None:
    e = engine_with(active=True)
    threading.Timer(0.5, lambda: e.set_active("m", False)).start()  # moved away
    started = time.monotonic()
    drain(e, 30.0, threading.Event())
    assert 0.4 < time.monotonic() - started < 3.0


def test_the_drain_ends_after_its_seconds_and_says_what_stays(
    caplog: pytest.LogCaptureFixture,
) -> None:
    started = time.monotonic()
    drain(engine_with(active=True), 0.5, threading.Event())
    assert 0.4 < time.monotonic() - started < 3.0
    assert "1 monitor(s) still here after 0.5s: m (their state ends here)" in caplog.text


def test_a_second_signal_ends_the_drain() -> None:
    hurry = threading.Event()
    threading.Timer(0.3, hurry.set).start()
    started = time.monotonic()
    drain(engine_with(active=True), 30.0, hurry)
    assert time.monotonic() - started < 3.0


def test_the_drain_flag_is_checked() -> None:
    p = argparse.ArgumentParser()
    add_arguments(p)
    assert p.parse_args(["--name", "a", "--drain", "45"]).drain == 45.0
    assert p.parse_args(["--name", "a"]).drain == 0.0
    with pytest.raises(SystemExit):
        p.parse_args(["--name", "a", "--drain", "-1"])
