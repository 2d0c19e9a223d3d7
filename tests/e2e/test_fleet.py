"""A fleet on the real cluster: two robots, each an edge node labelled with its name
(``edgerv.io/robot``: ``amr-a`` on ``edge``, ``amr-b`` on ``edge-b``), and a shared cloud
node. Each robot's publisher runs on its own node, in its own ROS namespace (``/amr_a``,
``/amr_b``), and the two edges do not reach each other; the cloud reaches both.

One Monitor gives an instance per robot, each on its robot's edge handler; a violation
published on robot B is B's (its status entry, an Event naming it), A stays clean; the
placement policy moves B's instance (under pressure) to the cloud while A's stays; a tier
edit moves both up and each back to its own robot's edge, never the other's, while each
robot's counter publishes, and each instance's verdicts equal ``edgerv check`` on its
robot's messages; robot B's real-time task late past its edge handler's deadline (the
chart's relative `--deadline cmd=100ms`, its robot's /amr_b/cmd) moves B's instance up by
the policy and home once on time, A's staying, with B's verdicts exact; robot B's node
deleted removes B's instance from the status and from
every handler and leaves A's as it was. (The project's cluster only: it has the node
edge-b, and `tests/cluster/cluster.py rejoin` registers it again.)
"""

from __future__ import annotations

import json
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

from edgerv.control.client import HandlerClient
from kit.chart import (
    ROOT,
    TOKEN,
    apply,
    counter_pod,
    counting_monitor,
    expected_verdicts,
    handler_pod,
    handler_tls,
    installed,
    monitor,
    running_operator,
    status,
    talker_pod,
    task_pod,
    until,
)
from kit.kube import Cluster

ROBOTS = {"amr-a": "edge", "amr-b": "edge-b"}  # robot -> its node
DEADLINE = "cmd=100ms"  # each edge handler's --deadline: its own robot's /NS/cmd
TRIP = 6000  # messages of B's counter while its instance goes up and home: 120 s
ROBOT = "edgerv.io/robot"
TIER = "edgerv.io/tier"


def _label(cluster: Cluster, node: str, *labels: str) -> None:
    cluster.run("label", "node", node, "--overwrite", *labels)


@pytest.fixture(scope="module")
def fleet(cluster: Cluster) -> Iterator[str]:
    """The two robots labelled, the chart installed (a handler on each edge and on the
    cloud), each robot's talker: A's always under the limit and slow (2 a second), B's
    0..99 every 20 ms (over the limit half the time); the operator running."""
    nodes = json.loads(cluster.run("get", "nodes", "-o", "json"))["items"]
    if "edge-b" not in {n["metadata"]["name"] for n in nodes}:
        pytest.skip("a cluster of yours: the fleet tests need the project's node edge-b")
    _label(cluster, "edge", f"{ROBOT}=amr-a")
    _label(cluster, "edge-b", f"{ROBOT}=amr-b", f"{TIER}=edge")
    try:
        # every robot's edge handler measures its own robot's task, given the relative form
        deadline = (
            "handler.tiers.edge.extraArgs[0]=--deadline",
            f"handler.tiers.edge.extraArgs[1]={DEADLINE}",
        )
        with installed(cluster, *deadline) as ns:
            for robot, node in ROBOTS.items():
                fast = robot == "amr-b"
                apply(
                    cluster,
                    ns,
                    talker_pod(
                        cluster,
                        name=f"talker-{robot}",
                        topic=f"/{robot.replace('-', '_')}/e2e/speed",
                        node={"kubernetes.io/hostname": node},
                        period=0.02 if fast else 0.5,
                        top=100 if fast else 10,
                    ),
                )
            with running_operator(cluster, ns) as runner:
                yield ns
            assert runner.exception is None, runner.output
    finally:
        _label(cluster, "edge", f"{ROBOT}-")
        _label(cluster, "edge-b", f"{ROBOT}-", f"{TIER}-")


@pytest.fixture(scope="module")
def operator_events(cluster: Cluster) -> Any:
    def events(ns: str, name: str) -> list[tuple[str, str]]:
        out = cluster.run(
            "get", "events", "-n", ns, "--field-selector", f"involvedObject.name={name}",
            "-o", "json",
        )  # fmt: skip
        return [(e["reason"], e["message"]) for e in json.loads(out)["items"]]

    return events


def robots_of(cluster: Cluster, ns: str, name: str) -> dict[str, Any]:
    return dict(status(cluster, ns, name).get("robots") or {})


def on(cluster: Cluster, ns: str, name: str, placement: dict[str, str]) -> dict[str, Any]:
    """The status once each robot's instance runs on the node given (robot -> node)."""

    def there() -> dict[str, Any] | None:
        s = status(cluster, ns, name)
        robots = s.get("robots") or {}
        ok = all(
            (robots.get(r) or {}).get("phase") == "Running"
            and ((robots.get(r) or {}).get("handler") or {}).get("node") == node
            for r, node in placement.items()
        )
        return s if ok and s.get("running") == len(placement) else None

    return dict(until(f"{name} on {placement}", there, timeout=180))


def test_one_monitor_runs_an_instance_per_robot_and_a_violation_is_its_robots(
    cluster: Cluster, fleet: str, operator_events: Any
) -> None:
    ns = fleet
    apply(cluster, ns, monitor("limits", "always (speed < limit)"))
    got = until(
        "B's violations",
        lambda: (
            (s := status(cluster, ns, "limits")).get("desired") == 2
            and ((s.get("robots") or {}).get("amr-b") or {}).get("verdicts", {}).get("violated")
            and s
        ),
        timeout=180,
    )
    robots = got["robots"]
    assert set(robots) == {"amr-a", "amr-b"}, got
    assert robots["amr-a"]["handler"]["node"] == "edge", got
    assert robots["amr-b"]["handler"]["node"] == "edge-b", got
    assert got["running"] == 2 and got["violated"] == 1, got
    a = until(
        "A's events",
        lambda: (e := robots_of(cluster, ns, "limits")["amr-a"]).get("events", 0) >= 5 and e,
    )
    assert a["verdicts"]["violated"] == 0, a  # A published under the limit, and was checked
    events = operator_events(ns, "limits")
    violated = [m for r, m in events if r == "Violated"]
    assert violated and all(m.startswith("robot amr-b: violated") for m in violated), events
    header, row = cluster.run("get", "monitors", "-n", ns).splitlines()[:2]

    def cell(column: str) -> str:  # columns are left-aligned; empty cells are blank
        at = header.index(column)
        return row[at:].split()[0]

    assert (cell("ROBOTS"), cell("VIOLATED")) == ("2", "1"), (header, row)


def test_the_policy_moves_the_pressured_robots_instance_up_and_leaves_the_other(
    cluster: Cluster, fleet: str
) -> None:
    """A 1,000-event sort window fills at B's 50 messages a second (the handlers release
    partial windows after an hour only): B's edge handler wants it moved, and the
    placement rounds hand B's instance to the cloud; A's, at 2 a second, stays."""
    ns = fleet
    pressured = monitor("pressured", "always (speed < limit)", sortThreshold=1000)
    pressured["spec"]["bufferCapacity"] = 1000
    apply(cluster, ns, pressured)
    got = on(cluster, ns, "pressured", {"amr-a": "edge", "amr-b": "cloud"})
    assert got["robots"]["amr-b"]["migrations"]["count"] >= 1, got
    assert "migrations" not in got["robots"]["amr-a"], got
    cluster.run("delete", "monitor", "pressured", "-n", ns, "--timeout=60s")


def test_a_tier_edit_moves_every_instance_up_and_each_back_with_exact_verdicts(
    cluster: Cluster, fleet: str, tmp_path: Path
) -> None:
    """Each robot's counter publishes COUNT messages on its own graph while a tier edit
    moves both instances to the cloud and each back to its own robot's edge, never the
    other's: each instance's verdicts over the whole run equal ``edgerv check`` on the
    messages its robot published (none lost, none twice, none of the other robot's)."""
    ns = fleet
    apply(cluster, ns, counting_monitor("counted"))
    on(cluster, ns, "counted", ROBOTS)
    for robot, node in ROBOTS.items():
        topic = f"/{robot.replace('-', '_')}/e2e/count"
        pod = counter_pod(cluster, f"counter-{robot}", topic, {"kubernetes.io/hostname": node})
        apply(cluster, ns, pod)
    until(
        "both robots' first violations",
        lambda: all(e.get("lastVerdict") for e in robots_of(cluster, ns, "counted").values()),
    )
    for tier, placement in (("cloud", {"amr-a": "cloud", "amr-b": "cloud"}), ("edge", ROBOTS)):
        before = robots_of(cluster, ns, "counted")
        cluster.run(
            "patch", "monitor", "counted", "-n", ns, "--type=merge",
            "-p", json.dumps({"spec": {"placement": {"tier": tier}}}),
        )  # fmt: skip
        got = on(cluster, ns, "counted", placement)
        for robot, entry in got["robots"].items():
            was = before[robot]
            moves = (was.get("migrations") or {}).get("count", 0)
            assert entry["migrations"]["count"] == moves + 1, (robot, was, entry)
            assert entry["migrations"]["last"]["reason"] == f"spec.placement.tier is {tier}"
            # the handoff kept its counts: they never go down
            assert entry["events"] >= was["events"], (robot, was, entry)
            assert entry["verdicts"]["violated"] >= was["verdicts"]["violated"]
    violations, last_step = expected_verdicts(tmp_path)

    def evaluated() -> dict[str, Any] | None:
        entries = robots_of(cluster, ns, "counted")
        steps = [(e.get("lastVerdict") or {}).get("step", 0) for e in entries.values()]
        return entries if len(steps) == 2 and min(steps) >= last_step else None

    got = until("every message of both robots evaluated", evaluated, timeout=150)
    for robot, entry in got.items():
        assert entry["verdicts"]["violated"] == violations, (robot, entry)  # none lost, twice
        assert entry["lastVerdict"]["step"] == last_step, (robot, entry)
        assert entry["handler"]["node"] == ROBOTS[robot], (robot, entry)
    for robot in ROBOTS:
        cluster.run("delete", "pod", f"counter-{robot}", "-n", ns, "--wait=false")
    cluster.run("delete", "monitor", "counted", "-n", ns, "--timeout=60s")


def test_a_late_robots_instance_goes_up_by_its_deadline_and_home_with_exact_verdicts(
    cluster: Cluster, fleet: str, tmp_path: Path
) -> None:
    """Robot B's real-time task runs late (its outputs /amr_b/cmd 140 ms after their
    inputs, past B's edge handler's 100 ms deadline) for 30 s, then on time: the
    placement policy moves B's instance to the cloud by the deadline and brings it home
    to B's edge once calm, while A's stays where it was; B's counter publishes all the
    while, and B's verdicts equal ``edgerv check`` on what it published."""
    ns = fleet
    apply(cluster, ns, counting_monitor("tripped"))
    on(cluster, ns, "tripped", ROBOTS)
    b = {"kubernetes.io/hostname": ROBOTS["amr-b"]}
    apply(cluster, ns, counter_pod(cluster, "trip-counter", "/amr_b/e2e/count", b, TRIP))
    apply(cluster, ns, task_pod(cluster, "task-amr-b", "/amr_b/cmd", b, late=30))
    try:
        up = on(cluster, ns, "tripped", {"amr-a": "edge", "amr-b": "cloud"})
        assert up["robots"]["amr-b"]["migrations"]["last"]["reason"] == "deadline", up
        until(
            "B's instance moved home",
            lambda: (
                (robots_of(cluster, ns, "tripped")["amr-b"].get("migrations") or {}).get("count")
                == 2
            ),
            timeout=240,
        )
        home = on(cluster, ns, "tripped", ROBOTS)
        assert home["robots"]["amr-b"]["migrations"]["last"]["reason"] == "calm below", home
        assert "migrations" not in home["robots"]["amr-a"], home  # A stayed
        violations, last_step = expected_verdicts(tmp_path, TRIP)
        got = until(
            "every message of B evaluated",
            lambda: (
                (e := robots_of(cluster, ns, "tripped")["amr-b"])
                .get("lastVerdict", {})
                .get("step", 0)
                >= last_step
                and e
            ),
            timeout=180,
        )
        assert got["verdicts"]["violated"] == violations, got  # none lost, none twice
        assert got["lastVerdict"]["step"] == last_step, got
    finally:
        for pod in ("trip-counter", "task-amr-b"):
            cluster.run("delete", "pod", pod, "-n", ns, "--wait=false")
        cluster.run("delete", "monitor", "tripped", "-n", ns, "--timeout=60s")
    on(cluster, ns, "limits", ROBOTS)  # B's other instances home too


def test_a_robot_whose_node_is_removed_loses_its_instance_and_the_others_stay(
    cluster: Cluster, fleet: str
) -> None:
    """`kubectl delete node edge-b`: robot B is gone (its pods run on until the pod
    garbage collector deletes them, and its handler then serves no one): B's instance is
    gone from the status and from every handler, A's runs on where it was, not moved nor
    restarted. (The node registers again afterwards: its kubelet restarted.)"""
    ns = fleet
    before = on(cluster, ns, "limits", ROBOTS)["robots"]["amr-a"]
    cloud = HandlerClient(
        f"{handler_pod(cluster, ns, 'cloud')['status']['hostIP']}:8470",
        TOKEN,
        handler_tls(cluster, ns),
    )
    assert any(m["name"].endswith(".amr-b") for m in cloud.monitors(timeout=10.0))
    cluster.run("delete", "node", "edge-b", "--timeout=60s")  # robot B's only node
    try:
        got = until(
            "B's instance gone",
            lambda: (s := status(cluster, ns, "limits")).get("desired") == 1 and s,
            timeout=120,
        )
        assert set(got["robots"]) == {"amr-a"}, got
        until(
            "B's instance removed from the cloud's handler",
            lambda: not [m for m in cloud.monitors(timeout=10.0) if m["name"].endswith(".amr-b")],
        )
        a = until(
            "A going on",
            lambda: (
                (e := robots_of(cluster, ns, "limits")["amr-a"])["events"] > before["events"] and e
            ),
        )
        assert a["handler"] == before["handler"], (before, a)  # not moved, not restarted
        moves = (a.get("migrations") or {}).get("count")
        assert moves == (before.get("migrations") or {}).get("count"), (before, a)
        assert a["verdicts"]["violated"] == 0, a
        got = status(cluster, ns, "limits")
        assert got["phase"] == "Running" and got["running"] == 1, got
        header, row = cluster.run("get", "monitors", "limits", "-n", ns).splitlines()[:2]
        assert row[header.index("ROBOTS") :].split()[0] == "1", (header, row)
    finally:
        subprocess.run(
            [sys.executable, str(ROOT / "tests" / "cluster" / "cluster.py"), "rejoin", "edge-b"],
            check=True,
            timeout=300,
        )
