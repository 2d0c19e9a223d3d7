"""The CPU budget's arithmetic and its errors without a Docker daemon: cores to a CFS quota
and back, the bounds, a stats document read, and what a caller is told when the daemon is
not there (a real client of a socket nobody listens on; tests/integration/
test_cpu_budget_docker.py sets a budget on a real daemon)."""

from __future__ import annotations

import math
from datetime import UTC, datetime
from pathlib import Path

import docker
import pytest

from edgerv.control.cpu_budget import (
    MIN_QUOTA_US,
    PERIOD_US,
    CpuBudgetError,
    CpuUse,
    DockerCpuBudget,
    bounded,
    checked_cores,
    cores_between,
    cores_of,
    cpu_use,
    instant,
    quota_for,
)


@pytest.mark.parametrize(
    ("cores", "period", "quota"),
    [(0.1, 100_000, 10_000), (1.0, 100_000, 100_000), (2.0, 100_000, 200_000),
     (0.5, 50_000, 25_000), (0.333, 100_000, 33_300), (0.001, 100_000, MIN_QUOTA_US)],
)  # fmt: skip
def test_cores_are_a_quota_of_each_period(cores: float, period: int, quota: int) -> None:
    assert quota_for(cores, period) == quota


def test_a_quota_reads_back_as_the_cores_it_was_set_from() -> None:
    for tenths in range(1, 21):
        cores = tenths / 10
        assert math.isclose(cores_of(quota_for(cores, PERIOD_US), PERIOD_US, 2.0), cores)


def test_no_quota_is_the_whole_machine_and_no_period_the_kernels() -> None:
    assert cores_of(0, 0, 8.0) == 8.0  # docker run without a limit
    assert cores_of(-1, 100_000, 8.0) == 8.0  # a quota removed (docker update --cpu-quota -1)
    assert cores_of(50_000, 0, 8.0) == 0.5  # --cpu-quota alone: the kernel's period
    assert cores_of(1_600_000, 100_000, 8.0) == 8.0  # more than the machine has


def test_a_budget_is_kept_between_the_floor_and_the_ceiling() -> None:
    assert bounded(0.01, 0.05, 2.0) == 0.05
    assert bounded(-3, 0.05, 2.0) == 0.05
    assert bounded(0.5, 0.05, 2.0) == 0.5
    assert bounded(7, 0.05, 2.0) == 2.0


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "1", None, True])
def test_a_budget_that_is_not_a_finite_number_is_refused(bad: object) -> None:
    with pytest.raises(ValueError, match="number of cores"):
        checked_cores(bad)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="number of cores"):
        bounded(bad, 0.05, 2.0)  # type: ignore[arg-type]


def test_cores_used_between_two_readings() -> None:
    a, b = CpuUse(10.0, 3.0, 0, 0, 0.0), CpuUse(12.0, 3.5, 0, 0, 0.0)
    assert cores_between(a, b) == 0.25
    with pytest.raises(ValueError, match="not after"):
        cores_between(b, a)


def test_a_stats_document_is_read_as_seconds_at_the_daemons_instant() -> None:
    # the Docker Engine API's GET /containers/{id}/stats: cpu_stats in nanoseconds, read
    # when the daemon read them (a reading may come a second after it was asked for)
    throttling = {"periods": 40, "throttled_periods": 30, "throttled_time": 1_200_000_000}
    stats = {
        "read": "2026-11-27T00:51:53.250000000Z",
        "cpu_stats": {
            "cpu_usage": {"total_usage": 2_500_000_000, "usage_in_usermode": 2_000_000_000},
            "system_cpu_usage": 9_000_000_000_000,
            "online_cpus": 2,
            "throttling_data": throttling,
        },
    }
    at = datetime(2026, 11, 27, 0, 51, 53, 250000, tzinfo=UTC).timestamp()
    assert cpu_use(stats) == CpuUse(at, 2.5, 40, 30, 1.2)
    # a container that does not run: its counters are zeros, or absent
    stopped = {"read": "0001-01-01T00:00:00Z", "cpu_stats": {"cpu_usage": {"total_usage": 0}}}
    assert cpu_use(stopped) is None
    assert cpu_use({}) is None


def test_the_daemons_instants_keep_their_fraction_and_zone() -> None:
    noon = datetime(2026, 11, 27, 12, tzinfo=UTC).timestamp()
    assert instant("2026-11-27T12:00:00Z") == noon
    assert instant("2026-11-27T12:00:00.123456789Z") == pytest.approx(noon + 0.123456789, abs=1e-6)
    assert instant("2026-11-27T13:00:00.5+01:00") == noon + 0.5
    for bad in ("", "2026-11-27", "2026-11-27T12:00:00", "yesterday"):
        with pytest.raises(ValueError, match="not an RFC 3339 instant"):
            instant(bad)


def test_a_floor_that_is_no_budget_is_refused_before_any_daemon_is_asked() -> None:
    with pytest.raises(ValueError, match="floor is a number of cores above 0"):
        DockerCpuBudget("edgerv-handler", floor=0)
    with pytest.raises(ValueError, match="floor is a finite number"):
        DockerCpuBudget("edgerv-handler", floor=math.nan)


def test_no_daemon_at_docker_host_says_where_and_what_to_do(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    where = f"unix://{tmp_path}/docker.sock"  # nobody listens there
    monkeypatch.setenv("DOCKER_HOST", where)
    with pytest.raises(CpuBudgetError) as raised:
        DockerCpuBudget("edgerv-handler")
    said = str(raised.value)
    assert said.startswith(f"the Docker daemon at {where} does not answer"), said
    assert "systemctl start docker" in said and "DOCKER_HOST" in said, said


def test_a_daemon_gone_from_a_given_client_says_so(tmp_path: Path) -> None:
    where = f"unix://{tmp_path}/docker.sock"
    client = docker.DockerClient(base_url=where, version="1.41")  # no version asked of it
    with pytest.raises(CpuBudgetError, match=r"does not answer.*systemctl start docker"):
        DockerCpuBudget("edgerv-handler", client=client)
