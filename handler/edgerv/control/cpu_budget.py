"""The edge handler's CPU budget set at run time: a CFS quota on its container's cgroup,
in cores, that the planner raises while the robot's real-time tasks leave headroom and
lowers as their deadline nears, so that verification never takes more than its share,
whatever monitors run (issue 37).

:class:`CpuBudget` is what a planner needs of a budget: its bounds, the budget now, a new
one. :class:`DockerCpuBudget` is the budget of a handler in a Docker container (a robot
without Kubernetes), changed through the Docker SDK as ``docker update --cpu-period
--cpu-quota`` changes it: the container keeps running and its monitors their state.
:meth:`DockerCpuBudget.use` reads the CPU the container's cgroup used, so that a caller
sees the handler follow its budget. A handler that cannot keep up under its budget says
so itself: its ingest lag in ``GET /v1/load`` grows (up to the time its subscriptions'
queues hold), and once messages are lost its status on ``/diagnostics`` is WARN; the planner
then moves monitors instead.

What goes wrong with the daemon or the container is a :class:`CpuBudgetError`, whose
message says what failed and what to do (the Docker SDK not installed too: it is the
``planner`` extra's, imported by :class:`DockerCpuBudget` only); a budget that is not a
number is a ValueError.
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Iterator, Mapping
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime
from types import ModuleType
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # (imported by DockerCpuBudget: the rest of the module needs no Docker SDK)
    import docker  # type: ignore[import-untyped, unused-ignore]  # (typed with types-docker)

FLOOR_CORES = 0.05  # the least budget set: the handler still answers its API, and stops
PERIOD_US = 100_000  # the CFS period when the container has none of its own (the kernel's)
MIN_QUOTA_US = 1_000  # the least CFS quota the kernel takes
DEFAULT_SOCKET = "unix:///var/run/docker.sock"


class CpuBudgetError(Exception):
    """The budget could not be read or set; the message says why and what to do."""


class CpuBudget(Protocol):
    """A handler's CPU budget in cores, read and set at run time by a planner."""

    @property
    def floor(self) -> float:
        """The least budget :meth:`set_cores` sets: the handler never starves."""
        ...

    @property
    def ceiling(self) -> float:
        """The most: the machine's cores."""
        ...

    def cores(self) -> float:
        """The budget in force; no limit reads as :attr:`ceiling`."""
        ...

    def set_cores(self, cores: float) -> float:
        """Set the budget to ``cores`` within [floor, ceiling]; return the budget now in
        force (``cores`` rounded to what the mechanism can set)."""
        ...


@dataclass(frozen=True)
class CpuUse:
    """A container's CPU counters at one instant: its cgroup's, all its processes."""

    at: float  # when the daemon read the counters: seconds since the epoch, its clock
    seconds: float  # CPU time used since the container started, all cores together
    periods: int  # CFS periods in which it had tasks to run (0: no quota)
    throttled_periods: int  # of those, the periods in which it used its whole quota
    throttled_seconds: float  # the time its tasks waited for the next period


def cores_between(earlier: CpuUse, later: CpuUse) -> float:
    """The mean number of cores used between two readings."""
    span = later.at - earlier.at
    if span <= 0:
        raise ValueError(f"the later reading ({later.at}) is not after the earlier ({earlier.at})")
    return (later.seconds - earlier.seconds) / span


def checked_cores(cores: float, what: str = "a CPU budget") -> float:
    """``cores`` as a float; a ValueError when it is not a finite number."""
    if isinstance(cores, bool) or not isinstance(cores, int | float):
        raise ValueError(f"{what} is a number of cores, not {cores!r}")
    if not math.isfinite(cores):
        raise ValueError(f"{what} is a finite number of cores, not {cores}")
    return float(cores)


def bounded(cores: float, floor: float, ceiling: float) -> float:
    """``cores`` within [floor, ceiling]."""
    return min(max(checked_cores(cores), floor), ceiling)


def quota_for(cores: float, period_us: int) -> int:
    """The CFS quota (microseconds a period) that gives ``cores``; at least the kernel's
    least, :data:`MIN_QUOTA_US`."""
    return max(MIN_QUOTA_US, round(checked_cores(cores) * period_us))


def cores_of(quota_us: int, period_us: int, ceiling: float) -> float:
    """The budget a CFS quota and period give, at most ``ceiling``; no quota (0 or -1)
    gives ``ceiling``, and a period of 0 is the kernel's, :data:`PERIOD_US`."""
    if quota_us <= 0:
        return ceiling
    return min(ceiling, quota_us / (period_us if period_us > 0 else PERIOD_US))


def instant(text: str) -> float:
    """An RFC 3339 instant as Docker writes one (``2026-11-27T00:51:53.872123456Z``,
    nanoseconds, or an offset instead of Z) in seconds since the epoch; a ValueError when
    it is not one."""
    found = re.fullmatch(r"(\d{4}-\d\d-\d\dT\d\d:\d\d:\d\d)(?:\.(\d+))?(Z|[+-]\d\d:\d\d)", text)
    if found is None:
        raise ValueError(f"not an RFC 3339 instant: {text!r}")
    whole, fraction, zone = found.groups()
    at = datetime.fromisoformat(whole + ("+00:00" if zone == "Z" else zone))
    return at.timestamp() + (int(fraction) / 10 ** len(fraction) if fraction else 0.0)


def cpu_use(stats: Mapping[str, Any]) -> CpuUse | None:
    """The counters of one reading of the Docker API's container stats (``read``: when;
    ``cpu_stats``: nanoseconds); None when it has none (the container does not run)."""
    cpu = stats.get("cpu_stats") or {}
    total = (cpu.get("cpu_usage") or {}).get("total_usage")
    if not isinstance(total, int) or total <= 0:
        return None
    try:
        at = instant(str(stats.get("read")))
    except ValueError:
        return None
    throttling = cpu.get("throttling_data") or {}
    return CpuUse(
        at,
        total / 1e9,
        int(throttling.get("periods", 0)),
        int(throttling.get("throttled_periods", 0)),
        int(throttling.get("throttled_time", 0)) / 1e9,
    )


def docker_sdk() -> ModuleType:
    """The Docker SDK (``docker``, with ``docker.errors``); a :class:`CpuBudgetError`
    saying how to install it when it is not."""
    try:
        import docker  # type: ignore[import-untyped, unused-ignore]
        import docker.errors  # type: ignore[import-untyped, unused-ignore]
    except ImportError as exc:
        raise CpuBudgetError(
            f"the Docker SDK for Python is not installed ({exc}): pip install 'edgerv[planner]'"
        ) from exc
    return docker


class DockerCpuBudget:
    """The CPU budget of the handler in Docker container ``container`` (its name or id),
    set as its CFS quota (``cpu_period``, ``cpu_quota``) through the Docker SDK;
    ``client`` by default is the daemon of the environment (``DOCKER_HOST``, else the
    local socket), as for the ``docker`` command. The ceiling is the daemon's machine's
    cores. A container started with ``--cpus`` cannot take a quota (Docker refuses to mix
    the two): start the handler without ``--cpus``, or with ``--cpu-quota``."""

    def __init__(
        self,
        container: str,
        client: docker.DockerClient | None = None,
        floor: float = FLOOR_CORES,
    ) -> None:
        floor = checked_cores(floor, "the floor")
        if floor <= 0:
            raise ValueError(f"the floor is a number of cores above 0, not {floor}")
        self.name = container
        self._daemon = os.environ.get("DOCKER_HOST") or DEFAULT_SOCKET
        sdk = docker_sdk()
        self._own_client = client is None  # closed by close()
        if client is None:
            with self._answers("connect to it"):
                client = sdk.from_env()
        else:  # a local socket's URL is http+docker://localhost (docker-py's), saying nothing
            url = client.api.base_url
            self._daemon = "the client's socket" if url.startswith("http+docker:") else url
        self._client = client
        try:
            with self._answers(f"find container '{container}'"):
                self._container = client.containers.get(container)
                self._ceiling = float(client.info()["NCPU"])
            if floor > self._ceiling:
                raise ValueError(
                    f"the floor {floor:g} is above the machine's {self._ceiling:g} cores"
                )
        except BaseException:
            self.close()
            raise
        self._floor = floor

    @property
    def floor(self) -> float:
        return self._floor

    @property
    def ceiling(self) -> float:
        return self._ceiling

    @property
    def container_id(self) -> str:
        return str(self._container.id)

    def cores(self) -> float:
        host = self._host_config()
        nano = int(host.get("NanoCpus") or 0)
        if nano > 0:
            return min(self._ceiling, nano / 1e9)
        return cores_of(
            int(host.get("CpuQuota") or 0), int(host.get("CpuPeriod") or 0), self._ceiling
        )

    def set_cores(self, cores: float) -> float:
        wanted = bounded(cores, self._floor, self._ceiling)
        host = self._host_config()
        if int(host.get("NanoCpus") or 0) > 0:
            raise CpuBudgetError(
                f"container '{self.name}' was started with --cpus, and Docker changes such a "
                "limit only as --cpus, which its SDK cannot set: start the handler without "
                "--cpus (its first budget, if any, as --cpu-quota)"
            )
        period = int(host.get("CpuPeriod") or 0) or PERIOD_US
        quota = quota_for(wanted, period)
        with self._answers(f"set the CPU quota of container '{self.name}'"):
            self._container.update(cpu_period=period, cpu_quota=quota)
        return cores_of(quota, period, self._ceiling)

    def use(self) -> CpuUse:
        """The container's CPU counters now; :func:`cores_between` of two readings is the
        mean number of cores it used between them."""
        sdk = docker_sdk()
        with self._answers(f"read the CPU use of container '{self.name}'"):
            try:
                stats = self._container.stats(stream=False, one_shot=True)
            except sdk.errors.InvalidVersion:  # a daemon older than API 1.41
                stats = self._container.stats(stream=False)
        if not isinstance(stats, Mapping):
            raise CpuBudgetError(f"the Docker daemon at {self._daemon} sent no stats")
        use = cpu_use(stats)
        if use is None:
            raise CpuBudgetError(
                f"container '{self.name}' has no CPU counters: it is not running "
                f"(`docker ps --all --filter name={self.name}` says its state)"
            )
        return use

    def close(self) -> None:
        """Close the connection to the daemon, if it is this budget's own (no ``client``
        was given)."""
        if self._own_client:
            self._client.close()

    def _host_config(self) -> dict[str, Any]:
        with self._answers(f"read the limits of container '{self.name}'"):
            self._container.reload()
        return dict(self._container.attrs.get("HostConfig") or {})

    @contextmanager
    def _answers(self, what: str) -> Iterator[None]:
        """The Docker SDK's errors as a :class:`CpuBudgetError` saying what to do."""
        sdk = docker_sdk()
        try:
            yield
        except sdk.errors.NotFound as exc:
            raise CpuBudgetError(
                f"no container '{self.name}' on the Docker daemon at {self._daemon}: "
                "`docker ps --all` lists them; give the name `docker run --name` gave the "
                "handler's container, or its id"
            ) from exc
        except sdk.errors.APIError as exc:
            raise CpuBudgetError(
                f"the Docker daemon at {self._daemon} refused to {what}: {exc.explanation or exc}"
            ) from exc
        except (sdk.errors.DockerException, OSError) as exc:  # requests' errors are OSErrors
            raise CpuBudgetError(
                f"the Docker daemon at {self._daemon} does not answer ({exc}): start it "
                "(`systemctl start docker`), or set DOCKER_HOST to where it listens; the "
                "user needs access to its socket (the docker group)"
            ) from exc


_DOCKER_IS_A_BUDGET: type[CpuBudget] = DockerCpuBudget  # checked by mypy: the protocol is kept
