"""A fleet's cost to the operator (issue 36): one round over R robots x 200 Monitors, with
the handlers simulated at their API (one HTTP server each, on loopback, answering
``GET /v1/monitors`` and ``GET /v1/load`` as a handler running those instances would).

A round is what the operator does every few seconds: the survey and the placement round
(:func:`edgerv_operator.handlers.survey_and_tend`: the handlers' API calls), then each
Monitor's status refresh without Kubernetes (its instances from the nodes' labels, each
robot's entry and the totals, and the merge patch it would send: ``instances``,
``_fleet_status``, ``changed``). Each robot has one edge handler running its 200
instances; one cloud handler defines every instance, idle (as the operator defines each
instance on every handler that may run it). Three kinds of round: the first, from empty
statuses; idle, nothing changed since the last (robots parked); busy, every robot's
instances took events since the last (each edge handler's 200 reports changed, the
cloud's idle instances did not). The handlers answer as the handler's API does: given
the reader's cursor, only what changed (docs/protocol.md, "Reading only what changed").
Time is the operator's thread's CPU time (the simulated handlers answer on threads of
their own, not counted) and the wall time of the round, best of ROUNDS.

``python bench/fleet_round.py``: prints the table and the rows (bench/run_all.py's format).
"""

from __future__ import annotations

import json
import threading
import time
import urllib.parse
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

from edgerv.control.orchestrate import Orchestrator
from edgerv.core.robots import fleet_of, instance_name
from edgerv.handler.revisions import Revisions
from edgerv_operator.config import OperatorConfig
from edgerv_operator.documents import HandlerPod, handler_name
from edgerv_operator.handlers import (
    Handlers,
    Operator,
    _fleet_status,
    changed,
    instances,
    survey_and_tend,
)

MONITORS = 200
SIZES = (10, 100)  # robots
ROUNDS = 3
PHASES = ("first", "idle", "busy")
SPEC: dict[str, Any] = {
    "assertion": "always (running -> speed < limit)",
    "signals": {
        "running": {"topic": "/running", "type": "std_msgs/msg/Bool"},
        "speed": {"topic": "/speed", "type": "std_msgs/msg/Float64"},
    },
    "parameters": {"limit": 2},
}


def report(name: str, robot: str, active: bool) -> dict[str, Any]:
    """A handler's report on one instance (GET /v1/monitors' item)."""
    return {
        "name": name, "handler": "h", "active": active,
        "state": "pending" if active else "inactive", "assertion": SPEC["assertion"],
        "topics": ["/x/running", "/x/speed"], "automatonState": 0, "step": 1200,
        "buffer": {"events": 0, "letters": 0, "capacity": 4096, "fill": 0.0},
        "events": 2400 if active else 0, "droppedEvents": 0, "lateEvents": 0,
        "verdicts": {"violated": 3, "satisfied": 0} if active else {},
        "lastVerdict": {"verdict": "violated", "stamp": 10**18, "step": 1100} if active else None,
        "migrationWanted": False, "handoff": None, "epoch": 0, "peer": None,
        "placement": {"tier": None, "migrate": "auto", "maxLatencyMs": None, "robot": robot},
    }  # fmt: skip


def load(name: str, reports: list[dict[str, Any]]) -> dict[str, Any]:
    """GET /v1/load of a handler running ``reports``."""
    return {
        "handler": name,
        "monotonic": time.monotonic(),
        "cpuSeconds": 1.0,
        "host": None,
        "ingestLag": 0.0,
        "deadline": None,
        "monitors": {
            r["name"]: {
                "active": r["active"],
                "handoff": None,
                "epoch": 0,
                "peer": None,
                "events": r["events"],
                "cpuSeconds": 0.01,
                "migrationWanted": False,
                "placement": r["placement"],
            }
            for r in reports
        },
    }


class FakeHandler:
    """One handler's API: its listing and load report, answered as a handler does (the
    handler's own :class:`Revisions`: with the reader's cursor, only what changed since);
    requests counted."""

    calls = 0
    lock = threading.Lock()

    def __init__(self, name: str, reports: list[dict[str, Any]]) -> None:
        self.name, self.reports = name, reports
        self.listed, self.loaded = Revisions(), Revisions()
        fake = self

        class Answer(BaseHTTPRequestHandler):
            def do_GET(self) -> None:
                with FakeHandler.lock:
                    FakeHandler.calls += 1
                path, _, query = self.path.partition("?")
                since = urllib.parse.parse_qs(query).get("since", [None])[0]
                body = fake.answer(path, since)
                self.send_response(200)
                self.send_header("Content-Type", "application/json")
                self.send_header("Content-Length", str(len(body)))
                self.end_headers()
                self.wfile.write(body)

            def log_message(self, *_: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Answer)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def answer(self, path: str, since: str | None) -> bytes:
        with FakeHandler.lock:
            if path == "/v1/monitors":
                entries = {r["name"]: r for r in self.reports}
                changed, removed, cursor = self.listed.read(entries, since)
                doc: dict[str, Any] = {"handler": self.name, "monitors": list(changed.values())}
            else:
                doc = load(self.name, self.reports)
                changed, removed, cursor = self.loaded.read(doc["monitors"], since)
                doc["monitors"] = changed
            doc["cursor"] = cursor
            if removed is not None:
                doc["since"], doc["removed"] = since, removed
        return json.dumps(doc).encode()

    def tick(self) -> None:
        """A busy robot's round: every active instance took 100 more events."""
        with FakeHandler.lock:
            self.reports = [
                {**r, "events": r["events"] + 100, "step": r["step"] + 100} if r["active"] else r
                for r in self.reports
            ]


def measure(robots: int) -> dict[str, Any]:
    names = [f"amr-{k}" for k in range(robots)]
    nodes: dict[str, dict[str, str]] = {f"edge-{r}": {"edgerv.io/robot": r} for r in names}
    nodes["cloud"] = {}
    fleet = fleet_of(nodes)
    monitors = [f"m{i}" for i in range(MONITORS)]
    pods, servers = [], []
    for r in names:
        reports = [report(instance_name(handler_name("lab", m), r), r, True) for m in monitors]
        servers.append(FakeHandler(f"edge-{r}", reports))
        pods.append(HandlerPod(f"edge-{r}", "edge", f"127.0.0.1:{servers[-1].port}", robot=r))
    every = [
        report(instance_name(handler_name("lab", m), r), r, False) for r in names for m in monitors
    ]
    servers.append(FakeHandler("cloud", every))
    pods.append(HandlerPod("cloud", "cloud", f"127.0.0.1:{servers[-1].port}"))
    config = OperatorConfig.from_env(
        {"EDGERV_TOKEN": "t", "EDGERV_NAMESPACE": "edgerv", "EDGERV_PLAIN_HTTP": "true"}
    )
    op = Operator(config, Orchestrator([], config.policy, config.token, starts=False, tls=None))
    handlers = Handlers(pods, [], [])
    statuses: dict[str, dict[str, Any]] = {m: {} for m in monitors}
    rows = []
    for phase in PHASES:
        best: dict[str, float] = {}
        for _ in range(1 if phase == "first" else ROUNDS):
            if phase == "busy":
                for server in servers[:-1]:  # each robot's edge handler: its instances ran
                    server.tick()
            FakeHandler.calls = 0
            op.surveyed_at = op.placed_at = float("-inf")  # a round is due
            wall, cpu = time.perf_counter(), time.thread_time()
            survey_and_tend(op, handlers)
            survey = time.perf_counter() - wall
            patched = 0
            for m in monitors:
                found = instances(m, "lab", SPEC, fleet)
                new, _ = _fleet_status(op, statuses[m], found, 1, fleet)
                patch = changed(statuses[m], new)
                patched += len(json.dumps(patch)) if patch else 0
                statuses[m] = {**statuses[m], **new}  # (the patch applied)
            took = {
                "wall": time.perf_counter() - wall,
                "cpu": time.thread_time() - cpu,
                "survey": survey,
                "calls": FakeHandler.calls,
                "patched": patched,
            }
            best = took if not best or took["cpu"] < best["cpu"] else best
        rows.append({"robots": robots, "phase": phase, **best})
    for s in servers:
        s.server.shutdown()
    return {"rows": rows}


def main() -> list[dict[str, Any]]:
    results = [row for n in SIZES for row in measure(n)["rows"]]
    print(
        "| robots x monitors | round | wall s | CPU s | survey+placement s "
        "| handler API calls | status patched |"
    )
    print("|---|---|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['robots']} x {MONITORS} | {r['phase']} | {r['wall']:.2f} | {r['cpu']:.2f} | "
            f"{r['survey']:.2f} | {r['calls']} | {r['patched'] / 1e6:.2f} MB |"
        )
    rows = []
    small, large = SIZES
    for phase in PHASES:
        a, b = (next(r for r in results if r["robots"] == n and r["phase"] == phase) for n in SIZES)
        rows.append(
            {
                "name": f"a fleet's operator round ({phase}), {MONITORS} Monitors",
                "detail": f"survey, placement round and every Monitor's status over {small} and "
                f"{large} robots, handlers simulated at the API (an edge handler a robot, one "
                "cloud handler defining every instance); the status patches' size",
                "baseline": f"{small} robots: {a['cpu']:.2f} s CPU, {a['calls']} handler calls, "
                f"{a['patched'] / 1e6:.2f} MB patched",
                "measured": f"{large} robots: {b['cpu']:.2f} s CPU, {b['calls']} handler calls, "
                f"{b['patched'] / 1e6:.2f} MB patched",
                "ratio": f"{b['cpu'] / a['cpu']:.1f}x the CPU, {b['calls'] / a['calls']:.1f}x the "
                f"calls for {large // small}x the robots",
            }
        )
    return rows


if __name__ == "__main__":
    main()
