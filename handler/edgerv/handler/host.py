"""The CPUs a handler may run on: what they spent, busy and in all, since boot.

Read from ``/proc/stat`` (Linux; in a container it is the node's), over the CPUs of this
process's affinity (``os.sched_getaffinity``: a handler pinned beside the robot's
real-time task to one core reports that core; an unpinned one, the machine). Counters,
not rates: the reader of the load report turns two readings into the share of those
CPUs the robot's other tasks and the handler use, and so the headroom the edge has left.
"""

from __future__ import annotations

import os
from collections.abc import Collection
from dataclasses import dataclass
from pathlib import Path

from edgerv.control.wire import HostLoad

# /proc/stat's "cpuN" lines: user nice system idle iowait irq softirq steal (guest and
# guest_nice are counted in user and nice already). Idle time: idle and iowait.
IDLE_FIELDS = (3, 4)
COUNTED_FIELDS = 8


@dataclass(frozen=True)
class HostCpu:
    cores: int  # the CPUs counted
    busy_seconds: float  # those CPUs together, since boot
    total_seconds: float

    def json(self) -> HostLoad:
        return {
            "cores": self.cores,
            "busySeconds": self.busy_seconds,
            "totalSeconds": self.total_seconds,
        }


def parse_stat(text: str, ticks_per_second: float, cpus: Collection[int]) -> HostCpu | None:
    """The ``cpuN`` lines of ``/proc/stat`` text for N in ``cpus``, summed; None if it has
    none of them (not Linux's format)."""
    busy = total = cores = 0
    for line in text.splitlines():
        parts = line.split()
        if not parts or not parts[0].startswith("cpu") or not parts[0][3:].isdigit():
            continue
        if int(parts[0][3:]) not in cpus:
            continue
        try:
            ticks = [int(v) for v in parts[1 : 1 + COUNTED_FIELDS]]
        except ValueError:
            return None
        if len(ticks) <= IDLE_FIELDS[-1]:
            return None
        idle = sum(ticks[i] for i in IDLE_FIELDS)
        busy += sum(ticks) - idle
        total += sum(ticks)
        cores += 1
    if not cores:
        return None
    return HostCpu(cores, busy / ticks_per_second, total / ticks_per_second)


def read_host_cpu(path: Path = Path("/proc/stat")) -> HostCpu | None:
    """The counters of the CPUs this process may run on, or None where ``/proc/stat``
    cannot be read."""
    try:
        text = path.read_text()
        hz = float(os.sysconf("SC_CLK_TCK"))
        cpus = os.sched_getaffinity(0)
    except (OSError, ValueError):
        return None
    return parse_stat(text, hz, cpus)
