"""The deadline planner (issue 37): which monitors move up to the cloud, or come home to
the edge, solved exactly within a time budget.

A pure function (:func:`plan_moves`) of the edge's monitors (:class:`MonitorCost`: each
one's CPU cost on the edge, events/s, ``maxLatencyMs``, pinned, in a handoff), the edge's
reading (:class:`EdgeState`: the real-time task's p95 makespan and deadline, the CPU its
tasks leave for verification, the cloud's latency) and :class:`PlannerConfig`. It decides;
the policy around it keeps the waits in time (``deadline_wait``, the calm and cooldown
waits) and the handoff moves. One :class:`Plan` is one handoff batch, in one direction.

With ``ratio = p95 / deadline``, *verification* the cost of what runs on the edge (a
monitor in a handoff counts there, wherever it is bound: it may not have left, or be
arriving) and *allowed* ``headroom * (1 - margin)``:

* **Up** when ``ratio >= high``: free ``need = max(verification - allowed, shed)``:
  bring verification within the headroom less its margin, and at least ``shed``, what
  the deadline asks. Given the handler's whole CPU ``h`` on the edge (``handler_cpu``:
  its monitors, and what it spends besides them), ``shed = (1 - h) * (ratio / low -
  1)``: the real-time task shares its CPU with the handler, so its makespan stretches by
  ``1 / (1 - h)`` (processor sharing: the paper's 200 monitors at 15% of a core took the
  demo's loop from 102 to 121 ms, 102 / 0.85 = 120); bringing the p95 to the calm mark
  ``low`` takes ``h`` down to ``1 - (1 - h) * ratio / low`` (sized from the service
  times' p95 where that is smaller: a late loop's backlog is not sharing, :func:`sized_ratio`).
  Without ``handler_cpu``,
  ``shed = verification * (1 - low / ratio)``, the share of it by which the p95 is over
  the calm mark (a first-order model). Movable: on the edge, not pinned, not in a
  handoff, ``maxLatencyMs`` (if any) at least the cloud's latency. The plan frees at
  least ``need`` with, lexicographically, (1) the fewest monitors: each moved monitor's
  verdicts gain the cloud's latency, and each is a state transfer in the handoff; (2) of
  those, the fewest events/s: the verdicts per second made later and the traffic the
  link must carry. When the movable monitors cannot free ``need``, all of them move and
  the plan says by how much it falls short.
* **Home** when ``ratio <= low``: monitors on the cloud whose home is the edge (not
  pinned, not in a handoff) come back, their summed cost at most ``allowed -
  verification`` (the room; given ``handler_cpu``, also at most ``(1 - h) * (1 - ratio /
  low) * (1 - margin)``: by the same model, what keeps the p95 under the calm mark, so
  that what comes home does not send monitors up again), at most ``max_home`` of them,
  with (1) the most monitors, (2) of those, the most events/s.
* **Neither** between the two marks (the hysteresis band), without a deadline signal
  (``p95`` None), or when nothing may or needs to move.

A topic's ingestion (``EdgeState.topic_costs``: the middleware delivering its messages,
taking and decoding them, whatever number of monitors read it) counts in *verification*
while a monitor that counts on the edge reads it. Moving up frees it only with the last
of its readers there (none of them held); coming home pays it with the first reader of a
topic the edge does not read now. So the monitors freeing ``need`` with the fewest may
be a whole topic's readers, where their own costs alone would not free it.

Costs are counted in millionths of a core and rates in thousandths of an event per second
(:func:`microcores`, :func:`millievents`): integers, so the solver's feasibility and
objective are exact. The selection (:mod:`edgerv.core.selection`) is solved exactly
within ``time_budget``: the fewest (most) monitors, by sorting for each set of charged
topics the plan may free (pay for), then of those the fewest (most) events/s, an integer
program solved by SciPy's :func:`scipy.optimize.milp` (HiGHS); without topic charges the
count is the greedy rule's, exact by sorting (largest cost first reaches the need with
the fewest, smallest first fits the most). If the solver does not prove the optimum
within it (or its answer fails the exact check), the plan is the greedy rule's: today's
rule (the busiest first, until enough is shed) with the measured cost in place of its
proxy, the event rate: largest cost first up (and each charged topic's readers first,
the fewest of those tries), smallest cost (with the topics it would start reading) first
home. ``Plan.method`` says which made the plan.
SciPy is loaded before the first plan (:func:`~edgerv.core.selection.solver_ready`, 0.4
s); where it is not installed (the ``planner`` extra: a handler's image has none) the
greedy rule plans, and the plan's reason says why.

The second lever, :func:`handler_budget`: the edge handler's CPU budget (a cgroup quota,
cores) by the same model, lowered to the calm mark's ``1 - (1 - h) * ratio / low`` when
the deadline is at risk, raised to what the real-time tasks leave less the margin when
it is calm, within :class:`BudgetConfig`'s floor and ceiling and changed only past its
hysteresis and wait.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Literal

from edgerv.core.selection import (
    Charges,
    Item,
    Selection,
    fewest_freeing,
    freed,
    most_fitting,
    paid,
)

Tier = Literal["edge", "cloud"]
Method = Literal["milp", "greedy", "all", "none"]
TIERS: tuple[Tier, ...] = ("edge", "cloud")
MICRO = 1_000_000  # units of a core in a cost
MILLI = 1_000  # units of an event/s in a rate


def microcores(cores: float) -> int:
    """A cost in millionths of a core, rounded to the nearest: the planner's unit."""
    return round(cores * MICRO)


def millievents(per_second: float) -> int:
    """A rate in thousandths of an event per second, rounded to the nearest."""
    return round(per_second * MILLI)


def _finite_at_least(value: float, low: float) -> bool:
    return math.isfinite(value) and value >= low


@dataclass(frozen=True)
class MonitorCost:
    """One monitor as the planner weighs it."""

    name: str
    tier: Tier  # where it runs now (in a handoff: the tier it is moving from)
    cost: float  # cores it takes on the edge (its evaluation and its share of ingestion)
    events_per_second: float = 0.0
    max_latency_ms: float | None = None  # placement.maxLatencyMs; None: any latency
    pinned: bool = False  # placement.migrate: pinned
    in_handoff: bool = False  # being moved right now: left alone
    home: Tier = "edge"  # placement.tier: only a monitor whose home is the edge comes home
    topics: tuple[str, ...] = ()  # the topics it reads (their ingestion: EdgeState.topic_costs)

    def __post_init__(self) -> None:
        if not self.name:
            raise ValueError("a monitor needs a name")
        if self.tier not in TIERS or self.home not in TIERS:
            raise ValueError(f"monitor {self.name}: tiers are 'edge' and 'cloud'")
        if not _finite_at_least(self.cost, 0.0):
            raise ValueError(f"monitor {self.name}: cost {self.cost} is not >= 0 cores")
        if not _finite_at_least(self.events_per_second, 0.0):
            raise ValueError(f"monitor {self.name}: {self.events_per_second} events/s")
        if self.max_latency_ms is not None and not self.max_latency_ms >= 0:
            raise ValueError(f"monitor {self.name}: maxLatencyMs {self.max_latency_ms}")


@dataclass(frozen=True)
class EdgeState:
    """The edge's reading: the real-time task's deadline and what its tasks leave."""

    headroom: float  # cores the robot's real-time tasks leave for verification
    deadline: float  # the task's budget, seconds
    p95: float | None  # its makespans' 95th percentile, seconds; None: no signal
    cloud_latency_ms: float  # the cloud tier's latency from the robot (the link's RTT)
    # the handler's whole CPU on the edge, cores (its monitors and the rest); None: unknown
    handler_cpu: float | None = None
    # the real-time task's CPU per output (seconds of CPU a message of its deadline topic
    # took): what its CPUs spent besides the handler, per output; None: unknown
    task_work: float | None = None
    # cores each topic's ingestion takes on the edge (the middleware delivering its
    # messages, taking and decoding them), whatever number of monitors read it: freed when
    # the last of them leaves the edge, paid again when the first comes home
    topic_costs: Mapping[str, float] = field(default_factory=dict)
    # the 95th percentile of its outputs' service times (their makespans less the waits
    # behind the previous output: edgerv.core.deadline), seconds; None: not measured
    service_p95: float | None = None

    def __post_init__(self) -> None:
        if self.service_p95 is not None and not _finite_at_least(self.service_p95, 0.0):
            raise ValueError(f"service p95 {self.service_p95} is not >= 0 seconds")
        for topic, cost in self.topic_costs.items():
            if not _finite_at_least(cost, 0.0):
                raise ValueError(f"topic {topic}: ingestion {cost} is not >= 0 cores")
        if self.handler_cpu is not None and not _finite_at_least(self.handler_cpu, 0.0):
            raise ValueError(f"handler CPU {self.handler_cpu} is not >= 0 cores")
        if self.task_work is not None and not _finite_at_least(self.task_work, 0.0):
            raise ValueError(f"the task's work {self.task_work} is not >= 0 seconds")
        if not _finite_at_least(self.headroom, 0.0):
            raise ValueError(f"headroom {self.headroom} is not >= 0 cores")
        if not (math.isfinite(self.deadline) and self.deadline > 0):
            raise ValueError(f"deadline {self.deadline} is not > 0 seconds")
        if self.p95 is not None and not _finite_at_least(self.p95, 0.0):
            raise ValueError(f"p95 {self.p95} is not >= 0 seconds")
        if not _finite_at_least(self.cloud_latency_ms, 0.0):
            raise ValueError(f"cloud latency {self.cloud_latency_ms} is not >= 0 ms")

    @property
    def ratio(self) -> float | None:
        return None if self.p95 is None else self.p95 / self.deadline


@dataclass(frozen=True)
class PlannerConfig:
    high: float = 1.0  # p95 / deadline at or above: move up (the policy's deadline_high)
    low: float = 0.95  # at or below: monitors may come home (deadline_low)
    margin: float = 0.1  # share of the headroom verification leaves free, both ways
    max_home: int | None = None  # monitors brought home in one plan at most
    time_budget: float = 0.2  # seconds the solver may take; 0: the greedy rule only

    def __post_init__(self) -> None:
        if not (0 < self.low < self.high and math.isfinite(self.high)):
            raise ValueError("need 0 < low < high")
        if not 0 <= self.margin < 1:
            raise ValueError("need 0 <= margin < 1")
        if self.max_home is not None and self.max_home < 1:
            raise ValueError("need max_home >= 1 (or None: no limit)")
        if not _finite_at_least(self.time_budget, 0.0):
            raise ValueError("need time_budget >= 0 seconds")


@dataclass(frozen=True)
class Plan:
    """The monitors to move, by name, in one direction (never both)."""

    up: tuple[str, ...]  # to the cloud
    down: tuple[str, ...]  # home to the edge
    method: Method  # milp: the proven optimum; greedy: the fallback; all: no choice
    reason: str  # in words
    target_microcores: int = 0  # up: the cost to free; home: the room on the edge
    moved_microcores: int = 0  # the cost moved (freed, or brought home)
    events_milli: int = 0  # the events/s moved, in thousandths
    solver_seconds: float = 0.0  # wall time in the solver (0: not called)

    @property
    def objective(self) -> tuple[int, int]:
        """What the plan optimises, lexicographically: (monitors moved, events_milli);
        up minimises it, home maximises it."""
        return len(self.up) + len(self.down), self.events_milli


def _cores(units: int) -> str:
    return f"{units / MICRO:.3g} cores"


def _names(names: Sequence[str], most: int = 5) -> str:
    shown = ", ".join(names[:most])
    return shown if len(names) <= most else f"{shown} and {len(names) - most} more"


def plan_moves(
    monitors: Sequence[MonitorCost], edge: EdgeState, config: PlannerConfig | None = None
) -> Plan:
    """The plan for this reading. Raises ValueError for two monitors of one name."""
    c = config or PlannerConfig()
    ordered = sorted(monitors, key=lambda m: m.name)
    twice = sorted({a.name for a, b in itertools.pairwise(ordered) if a.name == b.name})
    if twice:
        raise ValueError(f"monitors named twice: {', '.join(twice)}")
    ratio = edge.ratio
    if ratio is None:
        return Plan((), (), "none", "no deadline signal: nothing moves without a reading")
    deadline = f"p95 {edge.p95 or 0.0:.4g} s of a {edge.deadline:.4g} s deadline ({ratio:.0%})"
    here = [m for m in ordered if m.tier == "edge" or m.in_handoff]
    charges = {t: g for t, g in map(_charge, edge.topic_costs.items()) if g > 0}
    read_here = {t for m in here for t in m.topics if t in charges}
    verification = sum(microcores(m.cost) for m in here) + sum(charges[t] for t in read_here)
    allowed = microcores(edge.headroom * (1 - c.margin))
    if ratio >= c.high:
        return _up(ordered, edge, c, ratio, verification, allowed, deadline, charges)
    if ratio > c.low:
        return Plan(
            (),
            (),
            "none",
            f"hysteresis: {deadline} is between the marks {c.low:.0%} (monitors come home "
            f"at or below) and {c.high:.0%} (they move up at or above)",
        )
    room = deadline_room(edge, c, ratio)
    away = {t: g for t, g in charges.items() if t not in read_here}
    return _home(ordered, c, verification, allowed, deadline, room, Charges(away))


def _charge(item: tuple[str, float]) -> tuple[str, int]:
    return item[0], microcores(item[1])


def sized_ratio(edge: EdgeState, c: PlannerConfig, ratio: float) -> float:
    """The ratio what moves is sized from: ``ratio``, or, measured, the service times' p95
    over the deadline where that is smaller: the makespans without the backlog a late
    loop queues (sharing the CPU stretches a loop's service times; its backlog stretches
    its makespans further, and drains once they are short enough again). Late
    (``ratio >= high``), at least ``high``: late makespans always free something (a
    loop whose deadline is longer than its inputs' period can queue with service times
    within it)."""
    sized = ratio if edge.service_p95 is None else min(ratio, edge.service_p95 / edge.deadline)
    return max(sized, c.high) if ratio >= c.high else sized


def calm_cpu(edge: EdgeState, c: PlannerConfig, ratio: float) -> float | None:
    """The handler's CPU (cores) at which the real-time task's p95 sits at the calm mark
    ``low``, the two sharing a core (processor sharing: the task's output takes its work
    ``W`` over the ``1 - h`` of the core the handler leaves it), read off the p95 itself,
    ``W = p95 * (1 - h)``: ``1 - (1 - h) * ratio / low``, ``ratio`` as :func:`sized_ratio`
    reads it (the service times where they are measured). Given the task's measured work
    (``task_work``), the smaller of that and ``1 - W / (low * deadline)``: the measured
    work is the task's mean over the last poll, which follows a change of the task's load
    sooner than the p95's window does, but not the loop's spread, which the p95 carries
    (the demo's loop: a p95 at 102% of its deadline where its work alone says 95%); and
    the deadline is the p95's. Past its deadline a loop's outputs queue behind late ones:
    its makespans' p95 grows more than sharing alone would make it, and read off it the
    plan would move more than the deadline needs (make demo: all 450 where the 254 at the
    IMU's rate were enough); its service times' does not. None without ``handler_cpu``.
    May be below 0: no share of the core keeps the deadline."""
    h = edge.handler_cpu
    if h is None:
        return None
    read_off = 1.0 - (1.0 - h) * sized_ratio(edge, c, ratio) / c.low
    if edge.task_work is None:
        return read_off
    return min(read_off, 1.0 - edge.task_work / (c.low * edge.deadline))


def _read_off(edge: EdgeState, c: PlannerConfig, ratio: float) -> str:
    """What the deadline's share of a plan up was read off, in words ("" without the
    handler's CPU)."""
    h, calm = edge.handler_cpu, calm_cpu(edge, c, ratio)
    if h is None or calm is None:
        return ""
    served = "" if edge.service_p95 is None else f", service times' p95 {edge.service_p95:.4g} s"
    work = "" if edge.task_work is None else f", the task's work {edge.task_work:.4g} s an output"
    return (
        f" (the handler at {_cores(microcores(h))}, calm at {calm:.3g} cores: read off a "
        f"ratio of {sized_ratio(edge, c, ratio):.0%}{served}{work})"
    )


def deadline_shed(edge: EdgeState, c: PlannerConfig, verification: int, ratio: float) -> int:
    """What the deadline asks to free (microcores): the handler's CPU above
    :func:`calm_cpu`; without ``handler_cpu``, the share of verification by which the p95
    is over the calm mark."""
    h, calm = edge.handler_cpu, calm_cpu(edge, c, ratio)
    if h is None or calm is None:
        return math.ceil(verification * (1 - c.low / sized_ratio(edge, c, ratio)))
    return math.ceil(max(0.0, h - calm) * MICRO)


def deadline_room(edge: EdgeState, c: PlannerConfig, ratio: float) -> int | None:
    """What may come home (microcores) and keep the p95 under the calm mark: the handler's
    CPU below :func:`calm_cpu`, less the margin; None without ``handler_cpu``."""
    h, calm = edge.handler_cpu, calm_cpu(edge, c, ratio)
    if h is None or calm is None:
        return None
    return math.floor(max(0.0, calm - h) * (1 - c.margin) * MICRO)


def _up(
    ordered: list[MonitorCost],
    edge: EdgeState,
    c: PlannerConfig,
    ratio: float,
    verification: int,
    allowed: int,
    deadline: str,
    charges: Mapping[str, int],
) -> Plan:
    at_risk = f"the deadline is at risk ({deadline}, high mark {c.high:.0%})"
    if verification <= 0:
        return Plan((), (), "none", f"{at_risk}, but no verification runs on the edge")
    need = max(verification - allowed, deadline_shed(edge, c, verification, ratio))
    on_edge = [m for m in ordered if m.tier == "edge"]
    pinned = [m.name for m in on_edge if m.pinned]
    moving = [m.name for m in on_edge if m.in_handoff and not m.pinned]
    far = [
        m.name
        for m in on_edge
        if not (m.pinned or m.in_handoff)
        and m.max_latency_ms is not None
        and m.max_latency_ms < edge.cloud_latency_ms
    ]
    held = set(pinned) | set(moving) | set(far)
    items = [_item(m) for m in on_edge if m.name not in held]
    # a topic's ingestion is freed only if every monitor reading it on the edge may move
    taken = {i.name for i in items}
    here = (m for m in ordered if m.tier == "edge" or m.in_handoff)
    stay = {t for m in here if m.name not in taken for t in m.topics}
    free = Charges({t: g for t, g in charges.items() if t not in stay})
    holds = "; ".join(
        f"{what} {_names(names)}"
        for what, names in (
            ("pinned:", pinned),
            (f"maxLatencyMs below the cloud's {edge.cloud_latency_ms:g} ms:", far),
            ("in a handoff:", moving),
        )
        if names
    )
    sizing = (
        f"verification takes {_cores(verification)} on the edge, the headroom less its "
        f"{c.margin:.0%} margin allows {_cores(allowed)}: {_cores(need)} to free"
        + _read_off(edge, c, ratio)
    )
    if need <= 0:  # (the task's measured work: the handler's CPU is not what makes it late)
        return Plan((), (), "none", f"{at_risk}, but by the real-time task's work {sizing}", 0)
    if not items:
        return Plan((), (), "none", f"{at_risk}: {sizing}, but no monitor may move ({holds})", need)
    movable = freed(items, items, free)
    if movable < need:
        return _made(
            items,
            "all",
            f"{at_risk}: {sizing}; the movable monitors free only {_cores(movable)}: all "
            f"{len(items)} move up, {_cores(need - movable)} short"
            + (f" ({holds})" if holds else ""),
            need,
            movable,
            up=True,
        )
    chosen = fewest_freeing(items, need, free, c.time_budget)
    if len(chosen.chosen) == len(items):
        return _made(
            items,
            "all",
            f"{at_risk}: {sizing}; only all the movable free it",
            need,
            movable,
            up=True,
        )
    done = freed(chosen.chosen, items, free)
    return _selected(chosen, f"{at_risk}: {sizing}", need, done, up=True)


def _item(m: MonitorCost) -> Item:
    return Item(m.name, microcores(m.cost), millievents(m.events_per_second), frozenset(m.topics))


def _home(
    ordered: list[MonitorCost],
    c: PlannerConfig,
    verification: int,
    allowed: int,
    deadline: str,
    deadline_room: int | None,
    charges: Charges,
) -> Plan:
    calm = f"the deadline is met ({deadline}, low mark {c.low:.0%})"
    away = [m for m in ordered if m.tier == "cloud" and m.home == "edge"]
    items = [_item(m) for m in away if not (m.pinned or m.in_handoff)]
    if not items:
        held = f" ({len(away)} pinned or in a handoff)" if away else ""
        return Plan((), (), "none", f"{calm}, and no monitor may come home{held}")
    room = allowed - verification
    sizing = (
        f"the headroom less its {c.margin:.0%} margin allows {_cores(allowed)}, verification "
        f"takes {_cores(verification)} on the edge: {_cores(max(0, room))} of room"
    )
    if deadline_room is not None and deadline_room < room:
        room = deadline_room
        sizing += f", {_cores(room)} by the deadline"
    limit = len(items) if c.max_home is None else min(c.max_home, len(items))
    chosen = most_fitting(items, room, limit, charges, c.time_budget)
    if not chosen.chosen:
        return Plan(
            (), (), "none", f"{calm}: {sizing}, and none of the {len(items)} away fits", room
        )
    cost = paid(chosen.chosen, charges)
    if len(chosen.chosen) == len(items):
        return _made(items, "all", f"{calm}: {sizing}; all of those away fit", room, cost, up=False)
    return _selected(chosen, f"{calm}: {sizing}", room, cost, up=False)


def _made(
    chosen: Sequence[Item],
    method: Method,
    reason: str,
    target: int,
    cost: int,
    up: bool,
    seconds: float = 0.0,
) -> Plan:
    """The plan moving ``chosen`` (``cost``: what it frees up, or takes home)."""
    names = tuple(sorted(i.name for i in chosen))
    events = sum(i.events for i in chosen)
    direction = "up" if up else "home"
    said = (
        f"{reason}; {len(names)} move {direction}: {_names(list(names))} "
        f"({_cores(cost)}, {events / MILLI:.6g} events/s)"
    )
    return Plan(
        names if up else (),
        () if up else names,
        method,
        said,
        target,
        cost,
        events,
        seconds,
    )


def _selected(chosen: Selection, reason: str, bound: int, cost: int, up: bool) -> Plan:
    criterion = "the fewest that free it" if up else "the most that fit"
    if chosen.method == "milp":
        said = (
            f"{reason}; {criterion}, and of those the {'fewest' if up else 'most'} events/s "
            f"(milp, proven optimal in {chosen.seconds * 1e3:.0f} ms)"
        )
    else:
        largest = "largest" if up else "smallest"
        said = f"{reason}; {criterion}, {largest} cost first (the greedy rule: {chosen.why})"
    return _made(chosen.chosen, chosen.method, said, bound, cost, up, chosen.seconds)


@dataclass(frozen=True)
class BudgetConfig:
    """The edge handler's CPU budget's bounds (cores) and its hysteresis."""

    floor: float  # the least budget: the handler still answers and keeps its state
    ceiling: float  # the most: the machine's cores, or less
    hysteresis: float = 0.1  # a change smaller than this share of the budget is not made
    wait: float = 2.0  # seconds after a change before the next (the p95's window refills)

    def __post_init__(self) -> None:
        if not (math.isfinite(self.ceiling) and 0 < self.floor <= self.ceiling):
            raise ValueError(
                f"need 0 < floor <= ceiling (floor {self.floor}, ceiling {self.ceiling})"
            )
        if not 0 <= self.hysteresis < 1:
            raise ValueError("need 0 <= hysteresis < 1")
        if not _finite_at_least(self.wait, 0.0):
            raise ValueError("need wait >= 0 seconds")


@dataclass(frozen=True)
class Budget:
    """The budget to be in force (cores) and why; ``previous`` the budget read before."""

    cores: float
    previous: float
    reason: str

    @property
    def changed(self) -> bool:
        return self.cores != self.previous


def handler_budget(
    edge: EdgeState | None,
    current: float,
    bounds: BudgetConfig,
    config: PlannerConfig | None = None,
    verification: float = 0.0,
    since_change: float = math.inf,
) -> Budget:
    """The edge handler's CPU budget (a cgroup quota, cores) for this reading; ``current``
    the budget in force, ``verification`` the cores of the monitors counted in
    ``edge.headroom``, ``since_change`` seconds since the budget last changed. Always
    within [floor, ceiling] (a budget outside is brought in at once); else, by the
    module's processor-sharing model with ``h = handler_cpu``:

    * **At risk** (``ratio >= high``): ``1 - (1 - h) * ratio / low`` (:func:`calm_cpu`:
      ``ratio`` as :func:`sized_ratio` reads it, and the task's work), the handler's CPU at
      which the p95 is at the calm mark; never raised.
    * **Calm** (``ratio <= low``): what the real-time tasks leave the handler less the
      margin, ``(headroom + h - verification) * (1 - margin)`` (the headroom counts the
      monitors' cost; the rest of the handler's CPU, its ingestion and API, is its own
      too), at most what keeps the p95 under the calm mark, ``h + deadline_room``, so that
      a raised budget does not put the deadline at risk; never below ``h``: a calm
      deadline is not helped by throttling what the handler does now.
    * **Unchanged** in the band, without a reading (no edge state, ``p95`` or
      ``handler_cpu``), within ``wait`` of the last change (the p95's window must
      refill first, or each round would lower it again for the same makespans), or when
      the new budget differs from ``current`` by at most ``hysteresis`` of it.
    """
    c = config or PlannerConfig()
    lo, hi = bounds.floor, bounds.ceiling
    given = float(current)
    held = min(max(given, lo), hi)
    if held != given:
        return Budget(held, given, f"the budget {given:.3g} cores is outside [{lo:g}, {hi:g}]")
    h = None if edge is None else edge.handler_cpu
    ratio = None if edge is None else edge.ratio
    if edge is None or ratio is None or h is None:
        return Budget(held, held, "no deadline or handler CPU reading: the budget stays")
    deadline = f"p95 {edge.p95 or 0.0:.4g} s of a {edge.deadline:.4g} s deadline ({ratio:.0%})"
    if since_change < bounds.wait:
        return Budget(
            held,
            held,
            f"changed {since_change:.1f} s ago: it stays {bounds.wait:g} s, until the "
            "deadline's window holds makespans measured since",
        )
    if ratio >= c.high:
        calm_mark = calm_cpu(edge, c, ratio)
        assert calm_mark is not None  # (h is known)
        target = min(held, calm_mark)
        why = (
            f"the deadline is at risk ({deadline}, high mark {c.high:.0%}): the handler's "
            f"CPU {h:.3g} cores at {max(0.0, calm_mark):.3g} brings the p95 to the calm mark "
            f"{c.low:.0%}" + (f", floor {lo:g}" if calm_mark < lo else "")
        )
    elif ratio <= c.low:
        left = edge.headroom + max(0.0, h - verification)
        share = left * (1 - c.margin)
        keeps = h + (deadline_room(edge, c, ratio) or 0) / MICRO
        target = min(share, keeps)
        why = (
            f"the deadline is met ({deadline}, low mark {c.low:.0%}): the real-time tasks "
            f"leave the handler {left:.3g} cores, {share:.3g} less the {c.margin:.0%} margin; "
            f"{keeps:.3g} keep the p95 under the calm mark; it uses {h:.3g}"
        )
        target = max(h, target)
    else:
        return Budget(
            held,
            held,
            f"hysteresis: {deadline} is between the marks {c.low:.0%} and {c.high:.0%}",
        )
    target = min(hi, max(lo, target))
    if abs(target - held) <= bounds.hysteresis * held:
        return Budget(
            held,
            held,
            f"{why}: {target:.3g} cores is within {bounds.hysteresis:.0%} of {held:.3g}, it stays",
        )
    return Budget(target, held, f"{why}: {held:.3g} -> {target:.3g} cores")
