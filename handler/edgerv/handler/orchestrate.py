"""``edgerv orchestrate``: a local orchestrator that polls handlers and moves monitors.

Each round it reads every handler's load report (``GET /v1/load``), turns the
counters into rates (:func:`build_reports`), asks the policy
(:func:`edgerv.core.placement.plan`) what to do, and does it: ``start`` activates
a monitor that runs nowhere, the other moves run the handoff of
:mod:`edgerv.handler.migrate`. Each action is printed as one JSON line on stdout.
A handler that does not answer is left out of that round (its monitors are not
moved: it may only be slow), and no monitor is started that round (it may run
on the silent one). A move that ends unsettled (``edgerv migrate``'s exit 3: a
handler did not answer, so where its monitors run is not confirmed) is recorded
with ``"ok": false`` and ``unsettled``; its monitors are settled at the start of
each later round (a record with ``"settle": true``) and not moved again until
that succeeds. Authenticates with ``EDGERV_TOKEN`` like the handlers.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import sys
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from typing import Any

from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    Placement,
    PolicyConfig,
    PolicyConfigError,
    PolicyMemory,
    placement_from_json,
    plan,
)
from edgerv.handler.client import ApiError, HandlerClient
from edgerv.handler.migrate import NotMoved, Unsettled, migrate, settle
from edgerv.handler.tls import ClientTls, add_client_arguments, client_tls
from edgerv.handler.token import Token

log = logging.getLogger("edgerv.orchestrate")


@dataclass(frozen=True)
class Target:
    tier: str
    address: str


def parse_handlers(text: str) -> list[Target]:
    """``edge=HOST:PORT,cloud=HOST:PORT`` (a tier may have several handlers)."""
    targets = []
    for i, item in enumerate(p.strip() for p in text.split(",")):
        tier, eq, address = item.partition("=")
        if not eq or not tier.strip() or not address.strip():
            raise InputError(
                [
                    Diagnostic(
                        Location("--handlers"),
                        f"item {i + 1} '{item}' is not TIER=HOST:PORT",
                        hint="e.g. --handlers edge=10.0.0.2:8080,cloud=10.0.0.9:8080",
                    )
                ]
            )
        targets.append(Target(tier.strip(), address.strip()))
    return targets


def parse_pairs(text: str, flag: str) -> dict[str, float]:
    """``edge=0,cloud=40``."""
    out = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, eq, value = item.partition("=")
        try:
            if not eq:
                raise ValueError
            out[key.strip()] = float(value)
        except ValueError:
            raise InputError([Diagnostic(Location(flag), f"'{item}' is not NAME=NUMBER")]) from None
    return out


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def deadline_reading(value: object) -> DeadlineReading | None:
    """The load report's ``deadline`` (milliseconds) as the policy reads it (seconds).

    None when the handler measures no deadline (``--deadline`` not given) or reports
    something else: the policy then goes without it."""
    if not isinstance(value, Mapping):
        return None
    budget, p95, count = (_number(value.get(k)) for k in ("budgetMs", "p95Ms", "count"))
    if budget is None or count is None:
        return None
    return DeadlineReading(budget / 1000, None if p95 is None else p95 / 1000, int(count))


@dataclass
class Counters:
    monotonic: float
    cpu_seconds: float
    events: Mapping[str, int]


def build_reports(
    loads: Mapping[Target, Mapping[str, Any]],
    previous: dict[Target, Counters],
) -> tuple[list[HandlerReport], dict[str, Placement], dict[str, Target]]:
    """Load reports -> the policy's inputs; updates ``previous`` (the last counters).

    CPU is the handler's share of one core since the last poll (the handler's data
    path is one Python thread); events per second likewise per monitor. On the
    first poll of a handler both are 0: nothing moves for load before a rate is known.
    A handler's ``deadline`` (``--deadline``) is a reading already: it counts at once.
    """
    reports: list[HandlerReport] = []
    placements: dict[str, Placement] = {}
    where: dict[str, Target] = {}
    for target, load in loads.items():
        name = str(load["handler"])
        now, cpu_s = float(load["monotonic"]), float(load["cpuSeconds"])
        monitors = load["monitors"]
        events = {m: int(d["events"]) for m, d in monitors.items()}
        last = previous.get(target)
        span = now - last.monotonic if last else 0.0
        cpu = (cpu_s - last.cpu_seconds) / span if last and span > 0 else 0.0
        rates = {
            m: (n - last.events.get(m, n)) / span if last and span > 0 else 0.0
            for m, n in events.items()
        }
        previous[target] = Counters(now, cpu_s, events)
        reports.append(
            HandlerReport(
                name=name,
                tier=target.tier,
                cpu=max(0.0, cpu),
                ingest_lag=float(load.get("ingestLag", 0.0)),
                deadline=deadline_reading(load.get("deadline")),
                monitors={
                    m: MonitorLoad(
                        active=bool(d["active"]),
                        events_per_second=max(0.0, rates[m]),
                        migration_wanted=bool(d["migrationWanted"]),
                        in_handoff=d.get("handoff") is not None,
                    )
                    for m, d in monitors.items()
                },
            )
        )
        where[name] = target
        for m, d in monitors.items():
            placements.setdefault(m, placement_from_json(d.get("placement") or {}))
    return reports, placements, where


class Orchestrator:
    def __init__(
        self,
        targets: Sequence[Target],
        config: PolicyConfig,
        token: Token,
        timeout: float = 30.0,
        grace: float = 1.0,
        starts: bool = True,
        tls: ClientTls | None = None,
    ) -> None:
        self.config = config
        self.token = token
        self.tls = tls
        self.targets: list[Target] = []
        self.clients: dict[Target, HandlerClient] = {}
        self.previous: dict[Target, Counters] = {}
        self.set_targets(targets)
        self.starts = starts  # start monitors that run nowhere (off: someone else does)
        self.memory = PolicyMemory()
        self.timeout, self.grace = timeout, grace
        self.warned: set[str] = set()
        # monitor -> (source, destination) of a move of ours that ended unsettled: it is
        # settled at the start of each round, and not moved again until it is
        self.unsettled: dict[str, tuple[Target, Target]] = {}

    def set_targets(self, targets: Sequence[Target]) -> None:
        """The handlers to poll from now on (the operator's change as pods come and go)."""
        self.targets = list(targets)
        self.clients = {t: self.clients.get(t) or self._new_client(t) for t in targets}
        self.previous = {t: c for t, c in self.previous.items() if t in targets}

    def poll(self) -> dict[Target, Mapping[str, Any]]:
        loads = {}
        for t, client in self.clients.items():
            try:
                loads[t] = client.get("/v1/load", timeout=5.0)
            except ApiError as exc:
                log.warning("%s (%s) left out of this round: %s", t.address, t.tier, exc)
        return loads

    def round(self) -> list[dict[str, Any]]:
        """Poll, decide, act; return what was done, one record per action."""
        loads = self.poll()
        done = self._settle(loads)
        reports, placements, where = build_reports(loads, self.previous)
        for m, p in placements.items():
            if p.tier is not None and p.tier not in self.config.tiers and m not in self.warned:
                self.warned.add(m)
                log.warning(
                    "monitor %s: placement.tier '%s' is not one of the tiers %s; "
                    "it starts on the lowest",
                    m,
                    p.tier,
                    ",".join(self.config.tiers),
                )
        moves = plan(reports, placements, self.config, self.memory, time.monotonic())
        if len(loads) < len(self.targets) or not self.starts:
            # A silent handler may run monitors the others only define: starting them
            # elsewhere could make two active copies. Only moves between those that answered.
            # (And none when starting is someone else's job: the operator's.)
            moves = [m for m in moves if m.source]
        moves = [m for m in moves if m.monitor not in self.unsettled]  # settled first
        for start in (m for m in moves if not m.source):
            client = self.clients[where[start.destination]]
            started = time.monotonic()
            record: dict[str, Any] = {
                "at": round(time.time(), 3),
                "monitors": [start.monitor],
                "from": None,
                "to": client.base,
                "reason": start.reason,
            }
            try:
                client.call(f"/v1/monitors/{start.monitor}/activate", check=True)
                record["ok"] = True
            except ApiError as exc:
                record["ok"], record["error"] = False, str(exc)
            record["ms"] = round((time.monotonic() - started) * 1000, 1)
            done.append(record)
        batches: dict[tuple[str, str, str], list[str]] = {}
        for move in (m for m in moves if m.source):  # one handoff per pair of handlers
            batches.setdefault((move.source, move.destination, move.reason), []).append(
                move.monitor
            )
        for (source, destination, reason), names in batches.items():
            src, dst = self.clients[where[source]], self.clients[where[destination]]
            record = {
                "at": round(time.time(), 3),
                "monitors": names,
                "from": src.base,
                "to": dst.base,
                "reason": reason,
            }
            started = time.monotonic()
            try:
                moved = migrate(src, dst, names, self.timeout, self.grace)
                record.update(ok=True, bytes=moved.snapshot_bytes, events=moved.letters)
                record.update({"already": moved.already} if moved.already else {})
                record.update({"note": moved.note} if moved.note else {})
            except Unsettled as exc:  # not done: settled before it moves again
                unsettled = exc.names or names
                record.update(ok=False, error=str(exc), unsettled=unsettled)
                pair = (where[source], where[destination])
                self.unsettled.update(dict.fromkeys(unsettled, pair))
            except NotMoved as exc:
                record.update(ok=False, error=str(exc), where=exc.where)
            except ApiError as exc:  # (not expected: migrate says where they run)
                record.update(ok=False, error=str(exc), unsettled=names)
                self.unsettled.update(dict.fromkeys(names, (where[source], where[destination])))
            record["ms"] = round((time.monotonic() - started) * 1000, 1)
            done.append(record)
        return done

    def _client(self, target: Target) -> HandlerClient:
        return self.clients.get(target) or self._new_client(target)

    def _new_client(self, target: Target) -> HandlerClient:
        return HandlerClient(target.address, self.token, self.tls)

    def _settle(self, loads: Mapping[Target, Mapping[str, Any]]) -> list[dict[str, Any]]:
        """First the moves of ours that ended unsettled: their sources settle what they
        still hold of them (:func:`settle`: ask the receiver, commit or resume; resume
        what sent nothing yet), retried each round until it is done. Then monitors any
        handler holds released for another interrupted handoff (a driver that died).
        Until then they stay in the handoff, and the policy leaves them alone."""
        done = []
        pending: dict[tuple[Target, Target], list[str]] = {}
        for name, pair in self.unsettled.items():
            pending.setdefault(pair, []).append(name)
        for (source, destination), names in pending.items():
            client = self._client(source)
            record = self._settled(client, names, {"to": self._client(destination).base})
            if record["ok"]:
                for name in names:
                    del self.unsettled[name]
            done.append(record)
        tried = {name for names in pending.values() for name in names}
        for target, load in loads.items():
            names = [
                m
                for m, d in load["monitors"].items()
                if d.get("handoff") == "released" and m not in tried
            ]
            if names:
                done.append(self._settled(self._client(target), names, {}))
        return done

    def _settled(
        self, client: HandlerClient, names: list[str], extra: dict[str, Any]
    ) -> dict[str, Any]:
        """Settle ``names`` on ``client``; the record of it."""
        record: dict[str, Any] = {
            "at": round(time.time(), 3),
            "monitors": names,
            "from": client.base,
            **extra,
            "settle": True,
        }
        try:
            record.update(ok=True, moved=settle(client, names, time.monotonic() + self.timeout))
        except ApiError as exc:
            record["ok"], record["error"] = False, str(exc)
        return record


def add_arguments(p: argparse.ArgumentParser) -> None:
    add_client_arguments(p)
    p.add_argument(
        "--handlers",
        required=True,
        metavar="TIER=HOST:PORT,...",
        help="the handlers and their tiers, e.g. edge=10.0.0.2:8080,cloud=10.0.0.9:8080 "
        "(HTTPS unless loopback: --ca-file; TIER=http://HOST:PORT asks for plain HTTP)",
    )
    p.add_argument(
        "--tiers",
        metavar="LOW,...,HIGH",
        help="the tiers in order, closest to the robot first (default: as --handlers lists them)",
    )
    p.add_argument(
        "--tier-latency",
        default="",
        metavar="TIER=MS,...",
        help="each tier's latency from the robot, for placement.maxLatencyMs",
    )
    p.add_argument("--interval", type=float, default=1.0, metavar="SECONDS")
    p.add_argument(
        "--calm", type=float, default=30.0, metavar="SECONDS", help="calm before coming down"
    )
    p.add_argument(
        "--cooldown", type=float, default=60.0, metavar="SECONDS", help="least time between moves"
    )
    defaults = {f.name: f.default for f in fields(PolicyConfig)}
    p.add_argument(
        "--max-moves-down",
        type=int,
        default=defaults["max_moves_down"],
        metavar="N",
        help="monitors brought down a tier per round below a calm handler (default %(default)s)",
    )
    p.add_argument(
        "--deadline-high",
        type=float,
        default=defaults["deadline_high"],
        metavar="RATIO",
        help="deadline pressure: a handler's p95 makespan / budget at or above this "
        "(default %(default)s; handlers started with --deadline)",
    )
    p.add_argument(
        "--deadline-low",
        type=float,
        default=defaults["deadline_low"],
        metavar="RATIO",
        help="calm needs p95 makespan / budget at or below this (default %(default)s)",
    )
    p.add_argument(
        "--deadline-shed",
        type=float,
        default=defaults["deadline_shed"],
        metavar="FRACTION",
        help="under deadline pressure, move at least this share of the handler's movable "
        "event load up a tier, busiest first (default %(default)s)",
    )
    p.add_argument(
        "--deadline-wait",
        type=float,
        default=defaults["deadline_wait"],
        metavar="SECONDS",
        help="after such a move, leave that handler's deadline alone this long "
        "(default %(default)s)",
    )
    p.add_argument("--timeout", type=float, default=30.0, metavar="SECONDS", help="per migration")
    p.add_argument("--once", action="store_true", help="one round (after a first poll), then exit")


def config_from(args: argparse.Namespace, targets: Sequence[Target]) -> PolicyConfig:
    tiers = (
        [t.strip() for t in args.tiers.split(",") if t.strip()]
        if args.tiers
        else list(dict.fromkeys(t.tier for t in targets))
    )
    unknown = sorted({t.tier for t in targets} - set(tiers))
    if unknown:
        raise InputError(
            [
                Diagnostic(
                    Location("--handlers"),
                    f"tier {', '.join(unknown)} is not in --tiers {','.join(tiers)}",
                )
            ]
        )
    try:
        return PolicyConfig(
            tiers=tuple(tiers),
            tier_latency_ms=parse_pairs(args.tier_latency, "--tier-latency"),
            calm_seconds=args.calm,
            cooldown_seconds=args.cooldown,
            max_moves_down=args.max_moves_down,
            deadline_high=args.deadline_high,
            deadline_low=args.deadline_low,
            deadline_shed=args.deadline_shed,
            deadline_wait=args.deadline_wait,
        )
    except PolicyConfigError as exc:
        flag = "--" + exc.setting.replace("_", "-")
        raise InputError([Diagnostic(Location(flag), str(exc))]) from None
    except ValueError as exc:
        raise InputError([Diagnostic(Location("--tiers"), str(exc))]) from None


def run(args: argparse.Namespace) -> int:
    try:
        targets = parse_handlers(args.handlers)
        config = config_from(args, targets)
        tls = client_tls(args)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    orchestrator = Orchestrator(
        targets, config, os.environ.get("EDGERV_TOKEN"), args.timeout, tls=tls
    )
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.once:  # two polls: the first gives the counters the rates start from
        build_reports(orchestrator.poll(), orchestrator.previous)
        time.sleep(min(args.interval, 1.0))
    while True:
        for record in orchestrator.round():
            print(json.dumps(record), flush=True)
        if args.once or stop.wait(args.interval):
            return 0
