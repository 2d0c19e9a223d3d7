"""The orchestrator: it polls handlers and moves monitors, in rounds (:class:`Orchestrator`;
``edgerv orchestrate`` runs it, :mod:`edgerv.control.orchestrate_command`, and so do
the operator's placement rounds).

Each round it reads every handler's load report (``GET /v1/load``), turns the
counters into rates (:func:`build_reports`), asks the policy
(:func:`edgerv.control.placement.plan`) what to do, and does it: ``start`` activates
a monitor that runs nowhere, the other moves run the handoff of
:mod:`edgerv.control.migrate`. Each action is a record (a JSON line of the command).
A handler that does not answer is left out of that round (its monitors are not
moved: it may only be slow), and no monitor is started that round (it may run
on the silent one). A move that ends unsettled (``edgerv migrate``'s exit 3: a
handler did not answer, so where its monitors run is not confirmed) is recorded
with ``"ok": false`` and ``unsettled``; its monitors are settled at the start of
each later round (a record with ``"settle": true``) and not moved again until
that succeeds. A round that moves nothing says why (:func:`why_nothing_moves`), once
each time the reason changes. Given a :class:`BudgetLever` (the container of one
handler, the edge's), each round after its moves sets that handler's CPU budget by
:func:`edgerv.core.planner.handler_budget` when it changes: a record with ``budget``
and ``from`` (cores); a :class:`~edgerv.control.cpu_budget.CpuBudgetError` is a record
with ``"ok": false``, once until it changes or a budget is set, and the rounds go on.
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable, Collection, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

from edgerv.control.client import ApiError, HandlerClient
from edgerv.control.cpu_budget import CpuBudget, CpuBudgetError
from edgerv.control.migrate import NotMoved, Unsettled, migrate, settle
from edgerv.control.placement import (
    DeadlineReading,
    HandlerReport,
    MonitorLoad,
    Move,
    PolicyConfig,
    PolicyMemory,
    deadline_at_risk,
    deadline_moved,
    deadline_ratio,
    deadline_waits,
    edge_state,
    is_loaded,
    is_pressured,
    measured,
    plan,
    still_waits,
    tier_allowed,
)
from edgerv.control.tls import ClientTls
from edgerv.control.token import Token
from edgerv.control.wire import LoadReport, placement_from_json
from edgerv.core.documents import Placement
from edgerv.core.planner import BudgetConfig, EdgeState, PlannerConfig, handler_budget
from edgerv.core.selection import solver_ready

log = logging.getLogger("edgerv.orchestrate")


@dataclass(frozen=True)
class Target:
    tier: str
    address: str
    robot: str | None = None  # the robot whose node the handler runs on (None: shared)


def _number(value: object) -> float | None:
    return float(value) if isinstance(value, int | float) and not isinstance(value, bool) else None


def deadline_reading(value: object) -> DeadlineReading | None:
    """The load report's ``deadline`` (milliseconds) as the policy reads it (seconds).

    None when the handler measures no deadline (``--deadline`` not given) or reports
    something else: the policy then goes without it."""
    if not isinstance(value, Mapping):
        return None
    budget, p95, count, misses, last, service = (
        _number(value.get(k))
        for k in ("budgetMs", "p95Ms", "count", "misses", "lastMs", "serviceP95Ms")
    )
    if budget is None or count is None:
        return None
    return DeadlineReading(
        budget / 1000,
        None if p95 is None else p95 / 1000,
        int(count),
        int(misses or 0),
        None if last is None else last / 1000,
        None if service is None else service / 1000,
    )


@dataclass
class Counters:
    monotonic: float
    cpu_seconds: float
    events: Mapping[str, int]
    monitor_cpu: Mapping[str, float] = field(default_factory=dict)  # cpuSeconds per monitor
    host: tuple[float, float] | None = None  # its CPUs' busy and total seconds
    outputs: int | None = None  # the deadline topic's messages so far (--deadline)
    taking: Mapping[str, float] = field(default_factory=dict)  # cpuSeconds per topic


def build_reports(
    loads: Mapping[Target, LoadReport],
    previous: dict[Target, Counters],
) -> tuple[list[HandlerReport], dict[str, Placement], dict[str, Target]]:
    """Load reports -> the policy's inputs; updates ``previous`` (the last counters).

    CPU is the handler's share of one core since the last poll (the handler's data
    path is one Python thread); events per second likewise per monitor. On the
    first poll of a handler both are 0: nothing moves for load before a rate is known.
    A handler's ``deadline`` (``--deadline``) is a reading already: it counts at once.
    A monitor's ``cpu`` (cores) is known from its second poll on where it runs (None
    before, and after its counter restarted: it moved or was redefined); the handler's
    ``headroom`` (cores its CPUs idle, plus what its monitors take) from its second, and
    with ``--deadline`` the real-time task's ``task_work`` (CPU seconds per output: what
    its CPUs spent besides the handler, per message of the deadline topic); what each
    topic's ingestion costs (:func:`topic_costs`) from its second, counted in the headroom
    with its monitors.
    """
    reports: list[HandlerReport] = []
    placements: dict[str, Placement] = {}
    where: dict[str, Target] = {}
    for target, load in loads.items():
        name = load["handler"]
        now, cpu_s = load["monotonic"], load["cpuSeconds"]
        monitors = load["monitors"]
        events = {m: d["events"] for m, d in monitors.items()}
        last = previous.get(target)
        span = now - last.monotonic if last else 0.0
        cpu = (cpu_s - last.cpu_seconds) / span if last and span > 0 else 0.0
        rates = {
            m: (n - last.events.get(m, n)) / span if last and span > 0 else 0.0
            for m, n in events.items()
        }
        spent = {m: d["cpuSeconds"] for m, d in monitors.items() if d["active"]}
        costs: dict[str, float | None] = {}
        for m, seconds in spent.items():
            before = last.monitor_cpu.get(m) if last else None
            ok = before is not None and seconds >= before and span > 0
            costs[m] = (seconds - before) / span if ok and before is not None else None
        taking = {t: d["cpuSeconds"] for t, d in load["topics"].items()}
        topics = topic_costs(taking, last.taking if last else None, span, max(0.0, cpu), costs)
        host = load["host"]
        busy_total = None if host is None else (host["busySeconds"], host["totalSeconds"])
        headroom = work = None
        reading = load["deadline"]
        outputs = None if reading is None else reading["messagesTotal"]
        if host is not None and busy_total and last and last.host:
            (busy, total), (busy0, total0) = busy_total, last.host
            if total > total0:  # its CPUs' busy share since the last poll, in cores
                used = host["cores"] * min(1.0, max(0.0, (busy - busy0) / (total - total0)))
                mine = sum(v for v in costs.values() if v is not None)
                headroom = host["cores"] - used + mine + sum(topics.values())
                # the real-time task's CPU per output: what its CPUs did besides the
                # handler, per message of the deadline topic
                made = None if outputs is None or last.outputs is None else outputs - last.outputs
                if made and made > 0 and span > 0:
                    work = max(0.0, used - max(0.0, cpu)) / (made / span)
        previous[target] = Counters(now, cpu_s, events, spent, busy_total, outputs, taking)
        reports.append(
            HandlerReport(
                name=name,
                tier=target.tier,
                cpu=max(0.0, cpu),
                ingest_lag=load["ingestLag"],
                reach_ms=load["reachMs"],
                deadline=deadline_reading(load["deadline"]),
                monitors={
                    m: MonitorLoad(
                        active=d["active"],
                        events_per_second=max(0.0, rates[m]),
                        migration_wanted=d["migrationWanted"],
                        in_handoff=d["handoff"] is not None,
                        cpu=costs.get(m),
                        topics=tuple(d["topics"]),
                    )
                    for m, d in monitors.items()
                },
                headroom=headroom,
                task_work=work,
                robot=target.robot,
                topics=topics,
            )
        )
        where[name] = target
        for m, d in monitors.items():
            placements.setdefault(m, placement_from_json(d["placement"]))
    return reports, placements, where


def topic_costs(
    taking: Mapping[str, float],
    before: Mapping[str, float] | None,
    span: float,
    cpu: float,
    monitors: Mapping[str, float | None],
) -> dict[str, float]:
    """What each topic's ingestion costs on a handler (cores), whatever number of its
    monitors read it: the handler's CPU besides its monitors' (``cpu`` less the costs in
    ``monitors``: the middleware delivering the messages, taking and decoding them, and
    what the handler does besides), shared among its topics in proportion to the CPU it
    spent taking and decoding each (``taking``: cpuSeconds counters, ``before`` at the
    last poll, ``span`` seconds ago). Empty before two polls, while a monitor's cost is
    not known, or when nothing was taken; a topic new since the last poll counts from 0.
    It is an upper bound: what the handler does with no topic at all (its API, its
    timers: about 0.02 cores) is counted in its topics too."""
    if before is None or span <= 0 or any(v is None for v in monitors.values()):
        return {}
    rates = {t: max(0.0, (s - before.get(t, 0.0)) / span) for t, s in taking.items()}
    total = sum(rates.values())
    if total <= 0:
        return {}
    besides = max(0.0, cpu - sum(v for v in monitors.values() if v is not None))
    return {t: besides * r / total for t, r in rates.items()}


@dataclass(frozen=True)
class Idle:
    """Why a round moved nothing: ``kind`` (one of :data:`IDLE_KINDS`), the sentence
    ``text`` (with its numbers), and ``key``: the kind and whom it is about, not the
    numbers. It is said again only when the key changes."""

    kind: str
    text: str
    key: tuple[object, ...] = ()


IDLE_KINDS = (
    "no answer",  # no handler answered this round
    "no monitors",  # no handler defines a monitor
    "not started",  # a monitor runs nowhere and is not started (a handler is silent, ...)
    "unsettled",  # the policy would move monitors an unsettled move left held: settled first
    "no deadline signal",  # a handler measures a deadline but has too few makespans yet
    "deadline met",  # the deadline is met (the numbers), nothing else presses
    "no traffic",  # under deadline pressure, but the movable monitors read no events
    "hysteresis",  # a monitor may come down later (calm, cooldown), or a deadline shed waits
    "placed",  # no pressure, and no monitor above its home tier: all where it would go
    "pinned",  # what would move is pinned (placement.migrate) or held by maxLatencyMs
    "no room",  # under pressure, but no handler of the tier above can take monitors
    "nothing to shed",  # under pressure, but runs no monitor (or the rule sheds nothing)
)


# after a round that said one of these, a missed deadline ends the wait for the next
WOKEN = frozenset({"no deadline signal", "deadline met"})


def _names(names: Sequence[str], most: int = 5) -> str:
    """``a, b and 3 more``."""
    shown = ", ".join(names[:most])
    return shown + (f" and {len(names) - most} more" if len(names) > most else "")


def _verb(names: Sequence[str], one: str, many: str) -> str:
    return one if len(names) == 1 else many


def _deadline_words(h: HandlerReport, c: PolicyConfig) -> str:
    """``p95 makespan 80.0 ms, 64% of its 125 ms budget`` (a reading with information)."""
    d, ratio = h.deadline, deadline_ratio(h, c)
    assert d is not None and d.p95 is not None and ratio is not None
    return f"p95 makespan {d.p95 * 1000:.1f} ms, {ratio:.0%} of its {d.budget * 1000:g} ms budget"


def _pressure(h: HandlerReport, c: PolicyConfig) -> list[str]:
    """What puts a handler under pressure, in words (none: it is not)."""
    words = []
    if h.cpu >= c.cpu_high:
        words.append(f"CPU {h.cpu:.0%}, high mark {c.cpu_high:.0%}")
    if h.ingest_lag >= c.lag_high:
        words.append(f"ingest lag {h.ingest_lag:.2f} s, high mark {c.lag_high:g} s")
    wanting = sorted(m for m, load in h.monitors.items() if load.active and load.migration_wanted)
    if wanting:
        words.append(f"{_names(wanting)} {_verb(wanting, 'wants', 'want')} to migrate")
    if deadline_at_risk(h, c):
        words.append(f"{_deadline_words(h, c)}, high mark {c.deadline_high:.0%}")
    return words


def _unrest(h: HandlerReport, c: PolicyConfig) -> str:
    """Why a handler is not calm, in words."""
    words = []
    if h.cpu > c.cpu_low:
        words.append(f"CPU {h.cpu:.0%}, calm at {c.cpu_low:.0%} or less")
    if h.ingest_lag > c.lag_low:
        words.append(f"ingest lag {h.ingest_lag:.2f} s, calm at {c.lag_low:g} s or less")
    wanting = sorted(m for m, load in h.monitors.items() if load.active and load.migration_wanted)
    if wanting:
        words.append(f"{_names(wanting)} {_verb(wanting, 'wants', 'want')} to migrate")
    ratio = deadline_ratio(h, c)
    if ratio is not None and ratio > c.deadline_low:
        words.append(f"{_deadline_words(h, c)}, calm at {c.deadline_low:.0%} or less")
    return "; ".join(words)


def _stuck(
    h: HandlerReport,
    reports: Sequence[HandlerReport],
    placements: Mapping[str, Placement],
    c: PolicyConfig,
    memory: PolicyMemory,
    now: float,
    unknown_rates: Collection[str],
) -> Idle:
    """Why a handler under pressure (``_pressure``) sheds nothing this round."""
    rank = {t: i for i, t in enumerate(c.tiers)}
    pressure = "; ".join(_pressure(h, c))
    key = (h.name,)
    active = sorted(h.active())
    if not active:
        return Idle(
            "nothing to shed",
            f"{h.name} is under pressure ({pressure}) but runs no monitor",
            ("nothing to shed", *key),
        )
    left = deadline_waits(memory, h, c, now)
    if not is_loaded(h, c) and left:
        since = (
            "the loop caught up with the outputs queued behind the move"
            if h.name in memory.deadline_caught_up
            else "the handoff"
        )
        return Idle(
            "hysteresis",
            f"hysteresis holds: {h.name}'s deadline is at risk ({pressure}), but monitors "
            f"were moved for its deadline: it counts again in {left:.1f} s, once its window "
            f"holds makespans measured since {since} (--deadline-wait {c.deadline_wait:g} s)",
            ("hysteresis", *key),
        )
    left = still_waits(memory.lag_moved, h, c, now)
    lag_only = h.cpu < c.cpu_high and not any(
        m.active and m.migration_wanted for m in h.monitors.values()
    )
    if lag_only and h.ingest_lag >= c.lag_high and left:
        return Idle(
            "hysteresis",
            f"hysteresis holds: {h.name}'s ingest lags ({pressure}), but monitors were "
            f"moved for that lag: it counts again in {left:.1f} s, once its backlog had "
            f"time to drain (--deadline-wait {c.deadline_wait:g} s)",
            ("hysteresis", *key),
        )
    if rank[h.tier] + 1 >= len(c.tiers):
        return Idle(
            "no room",
            f"{h.name} is under pressure ({pressure}) on the highest tier, {h.tier}: "
            "there is no tier above to move its monitors to",
            ("no room", *key),
        )
    up = c.tiers[rank[h.tier] + 1]
    there = sorted(b.name for b in reports if b.tier == up)
    if not [b for b in reports if b.tier == up and not is_pressured(b, c)]:
        which = (
            f"{_names(there)} {_verb(there, 'is', 'are')} under pressure too"
            if there
            else "none answered this round"
        )
        return Idle(
            "no room",
            f"{h.name} is under pressure ({pressure}), but no handler of the tier above, "
            f"{up}, can take monitors: {which}",
            ("no room", *key),
        )
    movable = [
        m
        for m in active
        if placements.get(m, Placement()).migrate == "auto"
        and tier_allowed(up, placements.get(m, Placement()), c)
    ]
    if not movable:
        pinned = [m for m in active if placements.get(m, Placement()).migrate == "pinned"]
        far = [m for m in active if m not in pinned]
        held = []
        if pinned:
            held.append(f"{_names(pinned)} pinned (placement.migrate: pinned)")
        if far:
            latency = c.tier_latency_ms.get(up, 0.0)
            held.append(
                f"{_names(far)} held by placement.maxLatencyMs (tier {up} is {latency:g} ms "
                "from the robot)"
            )
        return Idle(
            "pinned",
            f"pinned monitors: {h.name} is under pressure ({pressure}), but none of its "
            f"monitors may move up to {up}: {'; '.join(held)}",
            ("pinned", *key),
        )
    if not is_loaded(h, c) and not sum(h.monitors[m].events_per_second for m in movable):
        if h.name in unknown_rates:
            return Idle(
                "no traffic",
                f"{h.name}'s deadline is at risk ({pressure}), but its monitors' event rates "
                "are not known yet (its first poll): the deadline moves the busiest, from the "
                "next round on",
                ("no rates", *key),
            )
        return Idle(
            "no traffic",
            f"the monitors carry no traffic: {h.name}'s deadline is at risk ({pressure}), but "
            f"{_names(movable)} read no event since the last poll: the deadline moves the "
            "busiest monitors, and idle ones would free nothing",
            ("no traffic", *key),
        )
    return Idle(
        "nothing to shed",
        f"{h.name} is under pressure ({pressure}), but the policy sheds nothing: its CPU "
        f"{h.cpu:.0%} is at or below the target {c.cpu_target:.0%}",
        ("nothing to shed", *key),
    )


def _descents(
    reports: Sequence[HandlerReport],
    placements: Mapping[str, Placement],
    c: PolicyConfig,
    memory: PolicyMemory,
    now: float,
    unsettled: Collection[str],
) -> Idle | None:
    """Why no monitor above its home tier came down (None: there is none)."""
    rank = {t: i for i, t in enumerate(c.tiers)}
    timed: list[tuple[float, str, str]] = []  # (seconds left, text, monitor)
    waiting: list[tuple[str, str]] = []  # (text, monitor): until a handler is calm
    pinned: list[str] = []
    for h in sorted(reports, key=lambda h: (-rank[h.tier], h.name)):
        if rank[h.tier] == 0:
            continue
        down = c.tiers[rank[h.tier] - 1]
        for m in sorted(h.active()):
            p = placements.get(m, Placement())
            if rank[h.tier] <= rank.get(p.tier or "", 0) or m in unsettled:
                continue
            if p.migrate == "pinned" or not tier_allowed(down, p, c):
                pinned.append(f"{m} on {h.name}")
                continue
            below = sorted((b for b in reports if b.tier == down), key=lambda b: (b.cpu, b.name))
            calm = [b for b in below if b.name in memory.calm_since]
            if not below:
                waiting.append(
                    (f"{m} comes down from {h.name} once a handler of {down} answers", m)
                )
                continue
            if not calm:
                b = below[0]
                waiting.append(
                    (f"{m} comes down from {h.name} once {b.name} is calm ({_unrest(b, c)})", m)
                )
                continue
            b = min(calm, key=lambda b: (memory.calm_since[b.name], b.cpu, b.name))
            calm_left = c.calm_seconds - (now - memory.calm_since[b.name])
            bounces = memory.bounces.get(m, 0)
            moved_ago = now - memory.last_move.get(m, -math.inf)
            cool_left = c.cooldown_seconds * 2**bounces - moved_ago
            why = []
            if calm_left > 0:
                why.append(
                    f"{b.name} calm for {now - memory.calm_since[b.name]:.0f} s of "
                    f"--calm {c.calm_seconds:g} s"
                )
            if cool_left > 0:
                doubled = f", doubled {bounces} time(s) for bounces" if bounces else ""
                why.append(
                    f"it moved {moved_ago:.0f} s ago: --cooldown {c.cooldown_seconds:g} s{doubled}"
                )
            left = max(calm_left, cool_left, 0.0)
            timed.append(
                (
                    left,
                    f"{m} may come down from {h.name} to {b.name} in {left:.0f} s "
                    f"({'; '.join(why)})",
                    m,
                )
            )
    if timed or waiting:
        timed.sort()
        texts = [t for _, t, _ in timed] + [t for t, _ in waiting]
        more = f"; {len(texts) - 1} more wait" if len(texts) > 1 else ""
        subjects = sorted(m for *_, m in timed) + sorted(m for _, m in waiting)
        return Idle("hysteresis", f"hysteresis holds: {texts[0]}{more}", ("down", *subjects))
    if pinned:
        return Idle(
            "pinned",
            f"pinned monitors: {_names(pinned)} {_verb(pinned, 'runs', 'run')} above its "
            "home tier and may not come down (placement.migrate: pinned, until a handler "
            "of a lower tier it may start on defines it; or placement.maxLatencyMs)",
            ("pinned", *pinned),
        )
    return None


def why_nothing_moves(
    reports: Sequence[HandlerReport],
    placements: Mapping[str, Placement],
    config: PolicyConfig,
    memory: PolicyMemory,
    now: float,
    planned: Sequence[Move] = (),
    silent: Sequence[str] = (),
    starts: bool = True,
    unsettled: Collection[str] = (),
    unknown_rates: Collection[str] = (),
) -> Idle:
    """Why a round moves nothing, from what the policy saw (:func:`plan`'s inputs, after
    it ran at ``now``): ``planned`` the policy's moves that the round held back,
    ``silent`` the handlers that did not answer, ``starts`` whether it starts monitors,
    ``unsettled`` the monitors whose move ended unsettled, ``unknown_rates`` the handlers
    polled for the first time (their monitors' event rates are not known yet).

    In this order: nothing to decide on; moves held back; a handler under pressure that
    sheds nothing (why); a monitor above its home tier that may not come down yet (the
    hysteresis, and how long) or at all (pinned); else what the deadline reads (no signal
    yet, or met with margin), else everything is where it would go. Tiers' latencies as
    the policy saw them (placement.measured)."""
    c = measured(config, reports)
    if not reports:
        return Idle("no answer", "no handler answered this round", ("no answer",))
    if not any(h.monitors for h in reports):
        return Idle("no monitors", "no handler defines a monitor", ("no monitors",))
    starting = sorted(m.monitor for m in planned if not m.source)
    if starting:
        if not starts:
            why = "starting them is left to whoever defined them (the operator)"
        else:
            why = (
                f"none is started while {_names(list(silent))} does not answer: it may run "
                f"{_verb(starting, 'it', 'them')}"
            )
        return Idle(
            "not started",
            f"{_names(starting)} {_verb(starting, 'runs', 'run')} nowhere, and {why}",
            ("not started", *starting, *silent),
        )
    held = sorted(m.monitor for m in planned if m.source and m.monitor in unsettled)
    if held:
        return Idle(
            "unsettled",
            f"{_names(held)} {_verb(held, 'waits', 'wait')} until the move that left "
            f"{_verb(held, 'it', 'them')} unsettled is settled (tried at the start of each round)",
            ("unsettled", *held),
        )
    rank = {t: i for i, t in enumerate(c.tiers)}
    pressed = [h for h in sorted(reports, key=lambda h: (rank[h.tier], h.name)) if _pressure(h, c)]

    def stuck(handlers: list[HandlerReport]) -> Idle | None:
        said = [_stuck(h, reports, placements, c, memory, now, unknown_rates) for h in handlers]
        if not said:
            return None
        return Idle(said[0].kind, "; ".join(i.text for i in said), tuple(i.key for i in said))

    # (one that runs no monitor has nothing to move: said after what may come down to it)
    found = (
        stuck([h for h in pressed if h.active()])
        or _descents(reports, placements, c, memory, now, unsettled)
        or stuck([h for h in pressed if not h.active()])
    )
    if found is not None:
        return found
    timed = sorted((h for h in reports if h.deadline is not None), key=lambda h: h.name)
    blind = [h for h in timed if deadline_ratio(h, c) is None]
    if blind:
        said = [
            f"{h.name} has {h.deadline.count if h.deadline else 0} makespan(s) in its window, "
            f"{c.deadline_min_count} needed ({c.deadline_sure_misses} if all miss)"
            for h in blind
        ]
        return Idle(
            "no deadline signal",
            f"no deadline signal yet: {'; '.join(said)} (is the --deadline topic published, "
            "its header stamped with the robot's clock?)",
            ("no deadline signal", *(h.name for h in blind)),
        )
    if timed:
        said = [f"{h.name}'s {_deadline_words(h, c)}" for h in timed]
        if all((deadline_ratio(h, c) or 0.0) <= c.deadline_low for h in timed):
            met, marks = (
                "with margin",
                f"monitors move up at {c.deadline_high:.0%}, --deadline-high",
            )
        else:  # between the marks: neither pressure nor calm
            met, marks = (
                "narrowly",
                (
                    f"monitors move up at {c.deadline_high:.0%}, --deadline-high; the handler is "
                    f"calm at {c.deadline_low:.0%} or less, --deadline-low"
                ),
            )
        return Idle(
            "deadline met",
            f"the deadline is met {met}: {'; '.join(said)} ({marks})",
            ("deadline met", *(h.name for h in timed)),
        )
    loads = "; ".join(
        f"{h.name} CPU {h.cpu:.0%}, ingest lag {h.ingest_lag:.2f} s"
        for h in sorted(reports, key=lambda h: (rank[h.tier], h.name))
    )
    return Idle(
        "placed",
        "everything movable is already where it would go: no handler is under pressure "
        f"({loads}; monitors move up at CPU {c.cpu_high:.0%} or lag {c.lag_high:g} s), and "
        "no monitor runs above its home tier; no handler measures a deadline "
        "(edgerv handler --deadline TOPIC=DURATION)",
        ("placed",),
    )


@dataclass
class BudgetLever:
    """The CPU budget of ``handler``'s container, which the orchestrator sets each round
    within ``bounds`` (:func:`~edgerv.core.planner.handler_budget`)."""

    budget: CpuBudget
    handler: Target
    bounds: BudgetConfig
    container: str = ""  # its name, for the records
    changed_at: float = -math.inf  # monotonic: when a round last changed it
    failed: str = ""  # the last error reported (not said again until it changes)


def budget_reading(h: HandlerReport, c: PolicyConfig) -> tuple[EdgeState | None, float]:
    """``h``'s reading as :func:`~edgerv.core.planner.handler_budget` takes it (None: no
    headroom or deadline reading yet), and the cores of its monitors and topics counted
    in the headroom (those whose cost is known)."""
    verification = sum(m.cpu for m in h.monitors.values() if m.active and m.cpu is not None)
    verification += sum(h.topics.values())  # (counted in the headroom with them)
    state = edge_state(h, c, None)
    return state, verification


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
        on_idle: Callable[[Idle], None] | None = None,
        levers: Sequence[BudgetLever] = (),
    ) -> None:
        self.config = config
        # handlers' CPU budgets, each set each round (none: the budget is not ours)
        self.levers: list[BudgetLever] = list(levers)
        self.token = token
        self.tls = tls
        self.targets: list[Target] = []
        self.clients: dict[Target, HandlerClient] = {}
        self.previous: dict[Target, Counters] = {}
        self.seen: dict[Target, HandlerReport] = {}  # each handler as the last poll read it
        # each handler measuring a deadline: its misses since it started, as last polled
        self.misses: dict[Target, int] = {}
        # Orchestrator.wait's: a thread per handler that waits for its next miss, and its
        # client (not the rounds': a client is not thread-safe)
        self.watchers: dict[Target, threading.Thread] = {}
        self.watch_clients: dict[Target, HandlerClient] = {}
        self.woke = threading.Event()  # set by a watcher that saw a miss
        self.set_targets(targets)
        self.starts = starts  # start monitors that run nowhere (off: someone else does)
        self.memory = PolicyMemory()
        self.timeout, self.grace = timeout, grace
        self.warned: set[str] = set()
        # monitor -> (source, destination) of a move of ours that ended unsettled: it is
        # settled at the start of each round, and not moved again until it is
        self.unsettled: dict[str, tuple[Target, Target]] = {}
        # why the rounds move nothing: said when the reason changes (the last one's key)
        self.on_idle = on_idle or (lambda idle: log.info("nothing to move: %s", idle.text))
        self.idle: Idle | None = None
        if config.planner:  # its solver loaded now (0.4 s), not in the first plan's round
            solver_ready()

    def set_targets(self, targets: Sequence[Target]) -> None:
        """The handlers to poll from now on (the operator's change as pods come and go)."""
        self.targets = list(targets)
        self.clients = {t: self.clients.get(t) or self._new_client(t) for t in targets}
        self.previous = {t: c for t, c in self.previous.items() if t in targets}
        self.seen = {t: r for t, r in self.seen.items() if t in targets}
        self.misses = {t: n for t, n in self.misses.items() if t in targets}
        self.watch_clients = {t: c for t, c in self.watch_clients.items() if t in targets}
        self.watchers = {t: w for t, w in self.watchers.items() if t in targets}

    def set_levers(self, levers: Sequence[BudgetLever]) -> None:
        """The budgets to set from now on (the operator's, one a budgeted handler pod, as
        pods come and go); a lever kept from the last call keeps its history."""
        self.levers = list(levers)

    def poll(self) -> dict[Target, LoadReport]:
        loads = {}
        for t, client in self.clients.items():
            try:
                loads[t] = client.load(timeout=5.0)
            except ApiError as exc:
                log.warning("%s (%s) left out of this round: %s", t.address, t.tier, exc)
        return loads

    def wait(self, seconds: float, stop: threading.Event) -> Literal["stopped", "missed", "waited"]:
        """Between rounds: until ``stop`` is set ("stopped") or ``seconds`` pass
        ("waited"). After a round that found every deadline met or not yet measured, a
        handler measuring one that misses it ends the wait at once ("missed": ``GET
        /v1/deadline`` answers at its next miss): the round that moves monitors starts at
        the miss, not up to an interval later. Under pressure, or in a move's wake, the
        wait is the interval's: a round at every miss would only poll more."""
        watched = dict(self.misses) if self.idle is not None and self.idle.kind in WOKEN else {}
        woke = self.woke
        woke.clear()
        for target, misses in watched.items():
            if target in self.targets and not self._watching(target):
                watcher = threading.Thread(
                    target=self._watch,
                    args=(target, misses, seconds),
                    name=f"edgerv-deadline-{target.address}",
                    daemon=True,
                )
                self.watchers[target] = watcher
                watcher.start()
        end = time.monotonic() + seconds
        while not stop.is_set() and not woke.is_set() and (left := end - time.monotonic()) > 0:
            woke.wait(min(left, 0.05))  # (stop is a signal handler's: looked at each 50 ms)
        return "stopped" if stop.is_set() else "missed" if woke.is_set() else "waited"

    def _watching(self, target: Target) -> bool:
        watcher = self.watchers.get(target)
        return watcher is not None and watcher.is_alive()

    def _watch(self, target: Target, misses: int, seconds: float) -> None:
        """Wait for ``target``'s next missed deadline, up to ``seconds``, then wake the
        wait (a thread of its own, with a client of its own: a client is not
        thread-safe). One still waiting from an earlier wait wakes the next one."""
        client = self.watch_clients.get(target)
        if client is None:
            client = self.watch_clients[target] = self._new_client(target)
        try:
            reading = client.deadline(after=misses, wait=seconds)
        except ApiError as exc:  # (an older handler: 404) the wait is the interval's
            log.debug("%s: no wait for its deadline: %s", target.address, exc)
            return
        if reading["missesTotal"] > misses:
            self.woke.set()

    def round(self) -> list[dict[str, Any]]:
        """Poll, decide, act; return what was done, one record per action."""
        loads = self.poll()
        self.misses = {
            t: d["missesTotal"] for t, load in loads.items() if (d := load["deadline"]) is not None
        }
        done = self._settle(loads)
        first = {load["handler"] for t, load in loads.items() if t not in self.previous}
        reports, placements, where = build_reports(loads, self.previous)
        self.seen.update({where[r.name]: r for r in reports})
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
        now = time.monotonic()
        planned = plan(reports, placements, self.config, self.memory, now)
        moves = planned
        if len(loads) < len(self.targets) or not self.starts:
            # A silent handler may run monitors the others only define: starting them
            # elsewhere could make two active copies. Only moves between those that answered.
            # (And none when starting is someone else's job: the operator's.)
            moves = [m for m in moves if m.source]
        moves = [m for m in moves if m.monitor not in self.unsettled]  # settled first
        if moves:
            self.idle = None
        else:
            silent = [t.address for t in self.targets if t not in loads]
            self._said(
                why_nothing_moves(
                    reports,
                    placements,
                    self.config,
                    self.memory,
                    now,
                    planned=planned,
                    silent=silent,
                    starts=self.starts,
                    unsettled=self.unsettled,
                    unknown_rates=first,
                )
            )
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
        plans: dict[tuple[str, str, str], str] = {}  # a planned batch: its plan in words
        for move in (m for m in moves if m.source):  # one handoff per pair of handlers
            key = (move.source, move.destination, move.reason)
            batches.setdefault(key, []).append(move.monitor)
            if move.plan:
                plans[key] = move.plan
        for (source, destination, reason), names in batches.items():
            src, dst = self.clients[where[source]], self.clients[where[destination]]
            record = {
                "at": round(time.time(), 3),
                "monitors": names,
                "from": src.base,
                "to": dst.base,
                "reason": reason,
            }
            if (source, destination, reason) in plans:
                record["plan"] = plans[source, destination, reason]
            started = time.monotonic()
            try:
                moved = migrate(src, dst, names, self.timeout, self.grace)
                record.update(ok=True, bytes=moved.snapshot_bytes, events=moved.letters)
                # when each step of the handoff ended, in ms from its start (protocol.md)
                record["steps"] = {k: round(v * 1000, 1) for k, v in moved.steps.items()}
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
            # the deadline's window refills with makespans measured since the handoff
            # ended, not during it: the moves' own work weighs on the edge while it lasts
            settle = {"deadline": (source, 0.0), "calm below": (destination, 1.0)}.get(reason)
            if settle is not None and settle[0] in self.memory.deadline_moved:
                waits = settle[1] * self.config.deadline_wait  # (PolicyMemory.deadline_moved)
                deadline_moved(self.memory, settle[0], time.monotonic() + waits)
        for lever in self.levers:
            done.extend(self._budget(lever, reports, where, now))
        return done

    def _budget(
        self,
        lever: BudgetLever,
        reports: Sequence[HandlerReport],
        where: Mapping[str, Target],
        now: float,
    ) -> list[dict[str, Any]]:
        """Set the lever's handler's CPU budget for this round's reading, if it changes:
        its record (none when it stays, or when an error was reported already)."""
        found = [r for r in reports if where.get(r.name) == lever.handler]
        name = found[0].name if found else lever.handler.address
        c = self.config
        try:
            current = lever.budget.cores()
            state, verification = budget_reading(found[0], c) if found else (None, 0.0)
            decided = handler_budget(
                state,
                current,
                lever.bounds,
                PlannerConfig(high=c.deadline_high, low=c.deadline_low, margin=c.planner_margin),
                verification,
                now - lever.changed_at,
            )
            if not decided.changed:
                lever.failed = ""
                return []
            in_force = lever.budget.set_cores(decided.cores)
        except CpuBudgetError as exc:
            if str(exc) == lever.failed:
                return []
            lever.failed = str(exc)
            return [
                {
                    "at": round(time.time(), 3),
                    "handler": name,
                    "container": lever.container,
                    "ok": False,
                    "error": str(exc),
                }
            ]
        lever.changed_at, lever.failed = now, ""
        return [
            {
                "at": round(time.time(), 3),
                "budget": round(in_force, 4),
                "from": round(decided.previous, 4),
                "handler": name,
                "container": lever.container,
                "reason": decided.reason,
                "ok": True,
            }
        ]

    def _said(self, idle: Idle) -> None:
        """Say why this round moves nothing, unless the last round said it already."""
        if self.idle is None or idle.key != self.idle.key:
            self.on_idle(idle)
        self.idle = idle

    def _client(self, target: Target) -> HandlerClient:
        return self.clients.get(target) or self._new_client(target)

    def _new_client(self, target: Target) -> HandlerClient:
        return HandlerClient(target.address, self.token, self.tls)

    def _settle(self, loads: Mapping[Target, LoadReport]) -> list[dict[str, Any]]:
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
                if d["handoff"] == "released" and m not in tried
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
