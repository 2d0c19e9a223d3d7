"""The machine a handler runs on: the CPU its cores spent, busy and in all, since boot.

Read from ``/proc/stat`` (Linux; in a container it is the node's). Counters, not rates:
the reader of the load report turns two readings into the share of the machine the
robot's other tasks and the handler use, and so the headroom the edge has left.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

# /proc/stat's "cpu" line: user nice system idle iowait irq softirq steal (guest and
# guest_nice are counted in user and nice already). Idle time: idle and iowait.
IDLE_FIELDS = (3, 4)
COUNTED_FIELDS = 8


@dataclass(frozen=True)
class HostCpu:
    cores: int
    busy_seconds: float  # all cores together, since boot
    total_seconds: float

    def json(self) -> dict[str, float | int]:
        return {
            "cores": self.cores,
            "busySeconds": self.busy_seconds,
            "totalSeconds": self.total_seconds,
        }


def parse_stat(text: str, ticks_per_second: float) -> HostCpu | None:
    """The aggregate ``cpu`` line of ``/proc/stat`` text and its ``cpuN`` lines; None if
    it has none (not Linux's format)."""
    total_line: list[str] | None = None
    cores = 0
    for line in text.splitlines():
        parts = line.split()
        if not parts:
            continue
        if parts[0] == "cpu":
            total_line = parts[1 : 1 + COUNTED_FIELDS]
        elif parts[0].startswith("cpu") and parts[0][3:].isdigit():
            cores += 1
    if total_line is None or len(total_line) < IDLE_FIELDS[-1] + 1:
        return None
    try:
        ticks = [int(v) for v in total_line]
    except ValueError:
        return None
    idle = sum(ticks[i] for i in IDLE_FIELDS)
    total = sum(ticks)
    return HostCpu(max(cores, 1), (total - idle) / ticks_per_second, total / ticks_per_second)


def read_host_cpu(path: Path = Path("/proc/stat")) -> HostCpu | None:
    """This machine's CPU counters, or None where ``/proc/stat`` cannot be read."""
    try:
        text = path.read_text()
        hz = float(os.sysconf("SC_CLK_TCK"))
    except (OSError, ValueError):
        return None
    return parse_stat(text, hz)
