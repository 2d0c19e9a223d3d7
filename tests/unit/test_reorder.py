"""The reorder window: timestamp order across topics, bounded by a window."""

from __future__ import annotations

import random

from edgerv.handler.reorder import ReorderWindow

MS = 1_000_000


def test_late_messages_of_another_topic_are_put_back_in_order() -> None:
    w = ReorderWindow(0.02)
    out = w.add([(10 * MS, "/odom", 1), (12 * MS, "/odom", 2)], now=0.0)
    out += w.add([(11 * MS, "/stop", 3)], now=0.001)  # arrives after 12 ms, stamped 11 ms
    out += w.add([(40 * MS, "/odom", 4)], now=0.002)  # moves the window: 10..12 leave
    assert [item[2] for item in out] == [1, 3, 2]
    assert [item[2] for item in w.drain()] == [4]


def test_nothing_waits_longer_than_the_window() -> None:
    w = ReorderWindow(0.02)
    assert w.add([(5 * MS, "/a", 1)], now=1.0) == []
    assert w.due(now=1.01) == []
    assert [item[2] for item in w.due(now=1.02)] == [1]
    assert w.pending == [] and w.since is None


def test_random_disorder_within_the_window_is_undone() -> None:
    rng = random.Random(2)
    stamps = sorted(rng.sample(range(10**6), 500))
    items = [(s * 1000, "/x" if i % 2 else "/y", i) for i, s in enumerate(stamps)]
    # deliver in chunks whose order is scrambled by less than the window (5 ms)
    arrival = sorted(items, key=lambda it: it[0] + rng.randint(0, 4_000_000))
    w, out, now = ReorderWindow(0.005), [], 0.0
    for k in range(0, len(arrival), 7):
        now += 0.001
        out += w.add(sorted(arrival[k : k + 7]), now)
    out += w.drain()
    assert out == items


def test_under_steady_traffic_a_late_message_is_still_put_back_in_order() -> None:
    """The window never empties while messages come every millisecond: what decides that an
    item waited too long is its own time, not that of the first item ever pending (the
    take loop calls due() at every wake; it released everything every 20 ms)."""
    w, out = ReorderWindow(0.02), []
    for i in range(200):  # /odom every 1 ms, its stamps 1 ms apart, taken at once
        now = i / 1000
        out += w.add([(i * MS, "/odom", i)], now)
        if i == 150:  # stamped 145 ms: 5 ms late, within the window
            out += w.add([(145 * MS + 1, "/stop", "late")], now)
        out += w.due(now)
    out += w.drain()
    stamps = [item[0] for item in out]
    assert stamps == sorted(stamps) and len(out) == 201
