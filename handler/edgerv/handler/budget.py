"""One memory budget per handler (``--memory-budget``; docs/handler.md, "Limits on input").

The budget is shared out when the handler starts: the process as it is then (its
resident memory: Python, ROS, the API), the verdict lanes' queues, the request bodies
held at once and one decoded snapshot bundle (each share at most its own limit, at most
a fraction of the budget); the rest is the monitors'. A monitor costs what its buffers
take once full, and a snapshot of them (a handoff holds one): a monitor that would pass
the budget is refused at its definition. Nothing else the handler holds grows with its
input: past their bounds it drops, coalesces or refuses, and counts.

Pure but for :func:`resident_bytes` and the files :func:`container_limit` reads (given
as paths, for tests).
"""

from __future__ import annotations

import argparse
import os
import re
import threading
from dataclasses import dataclass, replace
from pathlib import Path

from edgerv.core.documents import MonitorSpec
from edgerv.handler.limits import Limits

MiB = 1 << 20
FLOOR = 512 * MiB  # the default budget is never below this (nor above the limit found)
MONITOR_BYTES = 16 << 10  # a monitor defined: its automaton, slot and runtime (~10 KiB idle)
EVENT_BYTES = 320  # an event in a sort buffer: its tuple, stamp and field values
LETTER_BYTES = 12  # a letter and its stamp (arrays of 4 and 8 bytes)
BODIES_SHARE = 8  # request bodies: at most 1/8 of the budget (and Limits.bodies)
BUNDLE_SHARE = 8  # a decoded bundle: at most 1/8 of the budget (and Limits.bundle)
NO_LIMIT = 1 << 60  # a cgroup v1 limit this high is none (it reads 9223372036854771712)

_UNITS = {
    "": 1,
    "b": 1,
    "k": 1000,
    "kb": 1000,
    "ki": 1 << 10,
    "kib": 1 << 10,
    "m": 1000**2,
    "mb": 1000**2,
    "mi": 1 << 20,
    "mib": 1 << 20,
    "g": 1000**3,
    "gb": 1000**3,
    "gi": 1 << 30,
    "gib": 1 << 30,
    "t": 1000**4,
    "tb": 1000**4,
    "ti": 1 << 40,
    "tib": 1 << 40,
}
_SIZE = re.compile(r"\s*(\d+(?:\.\d+)?)\s*([A-Za-z]*)\s*")


def parse_size(text: str) -> int:
    """A size in bytes: ``512MiB``, ``2Gi``, ``1.5G``, ``1000000`` (Kubernetes' units too)."""
    m = _SIZE.fullmatch(text)
    unit = m.group(2).lower() if m else ""
    if m is None or unit not in _UNITS:
        raise argparse.ArgumentTypeError(
            f"'{text}' is not a size: a number of bytes, or with a unit (e.g. 512MiB, 2Gi, 1.5G)"
        )
    return int(float(m.group(1)) * _UNITS[unit])


def size_text(n: int) -> str:
    return f"{n / MiB:.0f} MiB" if n >= 10 * MiB else f"{n:,} bytes"


def _read_int(path: Path) -> int | None:
    """A limit file's number; None: absent, unreadable, ``max`` or no limit."""
    try:
        text = path.read_text().strip()
    except OSError:
        return None
    if not text.isdigit():
        return None  # "max" (v2): no limit
    value = int(text)
    return value if 0 < value < NO_LIMIT else None


def container_limit(
    root: Path = Path("/sys/fs/cgroup"), self_cgroup: Path = Path("/proc/self/cgroup")
) -> int | None:
    """The memory limit of this process's cgroup (v2 ``memory.max``, v1
    ``memory.limit_in_bytes``), where a container sees it (the cgroup namespace's root)
    or under the process's own cgroup path; None without one."""
    paths: list[Path] = []
    try:
        lines = self_cgroup.read_text().splitlines()
    except OSError:
        lines = []
    for line in lines:
        _, controllers, path = [*line.split(":", 2), "", ""][:3]
        rel = path.lstrip("/")
        if controllers == "":  # v2: "0::/path"
            paths.append(root / rel / "memory.max")
        elif "memory" in controllers.split(","):  # v1: "4:memory:/path"
            paths.append(root / "memory" / rel / "memory.limit_in_bytes")
    paths += [root / "memory.max", root / "memory" / "memory.limit_in_bytes"]
    limits = [n for p in paths if (n := _read_int(p)) is not None]
    return min(limits) if limits else None


def physical_memory(meminfo: Path = Path("/proc/meminfo")) -> int | None:
    try:
        for line in meminfo.read_text().splitlines():
            if line.startswith("MemTotal:"):
                return int(line.split()[1]) * 1024
    except (OSError, ValueError, IndexError):
        return None
    return None


def default_budget(limit: int | None, memory: int | None) -> int:
    """Half the container's limit (else of the machine's memory), at least FLOOR but
    never above the limit itself."""
    whole = limit if limit is not None else memory
    if whole is None:
        return 2 * FLOOR
    return min(whole, max(whole // 2, FLOOR))


def resident_bytes(statm: Path = Path("/proc/self/statm")) -> int:
    """This process's resident memory now (0 where /proc does not say)."""
    try:
        return int(statm.read_text().split()[1]) * os.sysconf("SC_PAGE_SIZE")
    except (OSError, ValueError, IndexError):
        return 0


def monitor_cost(spec: MonitorSpec) -> int:
    """What a monitor may take once its buffers are full, with a snapshot of them."""
    events = min(spec.sort_threshold, spec.buffer_capacity)
    return MONITOR_BYTES + events * EVENT_BYTES + 2 * spec.buffer_capacity * LETTER_BYTES


@dataclass
class Shares:
    """The budget's fixed shares, taken at start."""

    process: int  # resident at start
    queues: int  # the verdict lanes' queues
    bodies: int  # request bodies held at once
    bundle: int  # one decoded snapshot bundle

    @property
    def total(self) -> int:
        return self.process + self.queues + self.bodies + self.bundle


class MemoryBudget:
    """The monitors' part of the budget, and the fixed shares. Thread-safe."""

    def __init__(self, total: int, shares: Shares, origin: str = "--memory-budget") -> None:
        self.total = total
        self.shares = shares
        self.origin = origin  # where the total came from, for the messages
        self._lock = threading.Lock()
        self._monitors: dict[str, int] = {}
        self.committed_monitors = 0
        self.refused = 0  # monitors refused for it

    @classmethod
    def plan(
        cls, total: int, limits: Limits, queues: int, process: int, origin: str
    ) -> MemoryBudget:
        bodies = min(limits.bodies, total // BODIES_SHARE)
        bundle = min(limits.bundle, total // BUNDLE_SHARE)
        return cls(total, Shares(process, queues, bodies, bundle), origin)

    def limits(self, given: Limits) -> Limits:
        """``given`` with its bodies and bundle within their shares."""
        return replace(given, bodies=self.shares.bodies, bundle=self.shares.bundle)

    @property
    def for_monitors(self) -> int:
        return self.total - self.shares.total

    def committed(self) -> int:
        return self.shares.total + self.committed_monitors

    def problem(self, costs: dict[str, int]) -> str | None:
        """Why monitors of these costs (by name: a redefinition replaces its cost) do not
        fit; None when they do."""
        with self._lock:
            after = self.committed_monitors + sum(
                cost - self._monitors.get(name, 0) for name, cost in costs.items()
            )
            if after <= self.for_monitors:
                return None
            held = self.committed_monitors
        return (
            f"it would take about {size_text(sum(costs.values()))} with its buffers full "
            f"(bufferCapacity and sortThreshold), and this handler's monitors have "
            f"{size_text(self.for_monitors - held)} left of their {size_text(self.for_monitors)} "
            f"in its memory budget of {size_text(self.total)} ({self.origin}): a smaller "
            "bufferCapacity, another handler, or a larger budget"
        )

    def commit(self, name: str, cost: int) -> None:
        with self._lock:
            self.committed_monitors += cost - self._monitors.get(name, 0)
            self._monitors[name] = cost

    def forget(self, name: str) -> None:
        with self._lock:
            self.committed_monitors -= self._monitors.pop(name, 0)

    def startup_problem(self) -> str | None:
        """Why the budget cannot hold the handler itself; None when it can."""
        if self.for_monitors > 0:
            return None
        s = self.shares
        return (
            f"{size_text(self.total)} is less than this handler takes before any monitor: "
            f"{size_text(s.process)} resident at start, {size_text(s.queues)} of verdict "
            f"queues, {size_text(s.bodies)} of request bodies and {size_text(s.bundle)} "
            "for a snapshot bundle: give more"
        )
