"""One memory budget per handler (budget.py): sizes, the default from the container's
cgroup limit (v1 and v2, files given as paths), its shares, and monitors refused at
their definition, through the engine and the API."""

from __future__ import annotations

import argparse
from pathlib import Path

import pytest

from edgerv.core.diagnostics import InputError
from edgerv.core.documents import parse_monitors_text
from edgerv.core.monitor import compile_monitor
from edgerv.handler.budget import (
    FLOOR,
    MemoryBudget,
    MiB,
    Shares,
    container_limit,
    default_budget,
    monitor_cost,
    parse_size,
    physical_memory,
)
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits

DOC = """apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: {name}}}
spec:
  assertion: "always (x < 5)"
  signals:
    x: {{topic: /x, type: std_msgs/msg/Int32, field: data}}
  bufferCapacity: {capacity}
  sortThreshold: 1
"""


def compiled(name: str, capacity: int):  # type: ignore[no-untyped-def]
    specs, diagnostics = parse_monitors_text("m.yaml", DOC.format(name=name, capacity=capacity))
    assert not diagnostics
    return compile_monitor(specs[0])


@pytest.mark.parametrize(
    ("text", "value"),
    [
        ("1000", 1000),
        ("512MiB", 512 << 20),
        ("512Mi", 512 << 20),
        ("2Gi", 2 << 30),
        ("1.5G", 1_500_000_000),
        ("64k", 64_000),
        (" 1 GiB ", 1 << 30),
    ],
)
def test_sizes_are_read_with_their_units(text: str, value: int) -> None:
    assert parse_size(text) == value


@pytest.mark.parametrize("text", ["", "GiB", "-1", "1 parsec", "1e9", "0x10"])
def test_a_size_that_is_none_says_what_one_is(text: str) -> None:
    with pytest.raises(argparse.ArgumentTypeError, match="is not a size"):
        parse_size(text)


def test_cgroup_v2_limit_at_the_namespace_root_and_under_the_own_path(tmp_path: Path) -> None:
    root = tmp_path / "cgroup"
    (root / "kubepods" / "pod1").mkdir(parents=True)
    (root / "memory.max").write_text("max\n")
    (root / "kubepods" / "pod1" / "memory.max").write_text(f"{1 << 30}\n")
    own = tmp_path / "self_cgroup"
    own.write_text("0::/kubepods/pod1\n")
    assert container_limit(root, own) == 1 << 30
    own.write_text("0::/\n")  # a container's namespace: its root is its own
    (root / "memory.max").write_text(f"{3 << 30}\n")
    assert container_limit(root, own) == 3 << 30


def test_cgroup_v1_limit_and_its_no_limit_value(tmp_path: Path) -> None:
    root = tmp_path / "cgroup"
    (root / "memory").mkdir(parents=True)
    own = tmp_path / "self_cgroup"
    own.write_text("12:cpu,cpuacct:/\n4:memory:/\n")
    (root / "memory" / "memory.limit_in_bytes").write_text("9223372036854771712\n")
    assert container_limit(root, own) is None
    (root / "memory" / "memory.limit_in_bytes").write_text(f"{768 << 20}\n")
    assert container_limit(root, own) == 768 << 20


def test_no_cgroup_files_no_limit(tmp_path: Path) -> None:
    assert container_limit(tmp_path / "none", tmp_path / "none2") is None


def test_physical_memory_from_meminfo(tmp_path: Path) -> None:
    meminfo = tmp_path / "meminfo"
    meminfo.write_text("MemTotal:        8000000 kB\nMemFree: 1 kB\n")
    assert physical_memory(meminfo) == 8_000_000 * 1024
    assert physical_memory(tmp_path / "absent") is None


def test_the_default_is_half_the_limit_at_least_the_floor_never_above_the_limit() -> None:
    assert default_budget(4 << 30, 64 << 30) == 2 << 30  # the container's, not the machine's
    assert default_budget(None, 16 << 30) == 8 << 30
    assert default_budget(768 * MiB, None) == FLOOR  # half is under the floor
    assert default_budget(300 * MiB, None) == 300 * MiB  # never above the limit itself
    assert default_budget(None, None) == 2 * FLOOR


def test_the_shares_take_bodies_and_bundle_within_their_limits_and_fractions() -> None:
    b = MemoryBudget.plan(1 << 30, Limits(), queues=10 * MiB, process=200 * MiB, origin="x")
    assert b.shares.bodies == 128 * MiB and b.shares.bundle == 128 * MiB  # 1/8 of 1 GiB
    limits = b.limits(Limits(connections=7))
    assert (limits.connections, limits.bodies, limits.bundle) == (7, 128 * MiB, 128 * MiB)
    assert b.for_monitors == (1 << 30) - 200 * MiB - 10 * MiB - 256 * MiB
    assert b.startup_problem() is None
    small = MemoryBudget.plan(200 * MiB, Limits(), queues=10 * MiB, process=190 * MiB, origin="x")
    assert "less than this handler takes before any monitor" in (small.startup_problem() or "")


def test_a_monitor_costs_its_buffers_as_they_will_fill() -> None:
    small, large = compiled("s", 100), compiled("l", 1_000_000)
    assert monitor_cost(large.spec) - monitor_cost(small.spec) > 10 * MiB
    assert monitor_cost(large.spec) < 100 * MiB


def budget_for(monitors_bytes: int) -> MemoryBudget:
    return MemoryBudget(monitors_bytes + 1000, Shares(1000, 0, 0, 0), "--memory-budget")


def test_the_engine_refuses_a_monitor_past_the_budget_at_its_definition() -> None:
    engine = Engine("h")
    small = compiled("a", 100)
    engine.budget = budget_for(3 * monitor_cost(small.spec))
    for name in ("a", "b", "c"):
        engine.put(compiled(name, 100), active=True)
    with pytest.raises(InputError) as refused:
        engine.put(compiled("d", 100), active=True)
    text = str(refused.value)
    assert "m.yaml:3" in text and "spec.bufferCapacity" in text and "'d'" in text
    assert "memory budget" in text and "--memory-budget" in text
    assert "d" not in engine.slots and engine.budget.refused == 1
    engine.put(compiled("a", 100), active=True)  # replacing one is its own cost again: fits
    engine.remove("a")
    engine.put(compiled("d", 100), active=True)  # room again
    assert engine.budget.committed_monitors == 3 * monitor_cost(small.spec)


def test_a_larger_capacity_replacing_a_monitor_is_refused_and_the_old_one_runs_on() -> None:
    engine = Engine("h")
    engine.budget = budget_for(monitor_cost(compiled("a", 100).spec))
    engine.put(compiled("a", 100), active=True)
    with pytest.raises(InputError):
        engine.put(compiled("a", 100_000), active=True)
    assert engine.slots["a"].capacity == 100


def test_monitors_together_are_all_or_nothing() -> None:
    engine = Engine("h")
    engine.budget = budget_for(2 * monitor_cost(compiled("a", 100).spec))
    with pytest.raises(InputError, match="monitors 'a', 'b', 'c' together"):
        engine.refuse_over_budget([compiled(n, 100) for n in "abc"])
    engine.refuse_over_budget([compiled(n, 100) for n in "ab"])
