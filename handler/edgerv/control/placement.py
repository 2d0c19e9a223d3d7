"""The placement policy: where monitors should run, from the handlers' load reports.

A pure function of its inputs (and of :class:`PolicyMemory`, which it updates),
shared by the local orchestrator and the Kubernetes operator. It decides; the
migration protocol moves.

* **Up** (the paper's section V): a handler is *under pressure* when one of its
  monitors wants to migrate (its buffer stays full), or its CPU or ingest lag is
  above the high mark, or the robot's real-time task it shares the CPU with is at
  risk of missing its deadline (*deadline pressure*: the 95th percentile of the
  task's makespan is at or above ``deadline_high`` times its budget, over a window
  of at least ``deadline_min_count`` measurements, or of ``deadline_sure_misses``
  or more that all missed the budget; a handler started with
  ``--deadline``, :mod:`edgerv.core.deadline`). Its movable monitors go one tier
  up: those that want to migrate first, then the busiest (most events freed) with
  the least added latency, until the load it sheds brings it to the CPU target
  and, under deadline pressure, is at least ``deadline_shed`` of its movable event
  load (reason ``deadline``; before the monitors' rates are known the deadline
  alone moves nothing). After such a shed the handler's deadline pressure is not
  acted on for ``deadline_wait`` seconds: its window must first fill with
  makespans measured after the move. And once the loop has caught up with the backlog
  the move left (the newest makespan a poll reads is within the budget again), not
  until ``deadline_wait`` after that: the outputs that queued behind late ones drain
  after the move, late, and their makespans would read as pressure the move has
  already relieved (:func:`deadline_waits`). A handler under any pressure receives no
  monitors. Robots that ask one shared handler for more than the room below its CPU
  target share that room, least served first (:func:`_shared_fairly`).
* **Down** (beyond the paper): a monitor above its home tier comes back one tier
  once the handler below has been calm (CPU and lag below the low marks, nobody
  wanting to migrate, the deadline's 95th percentile at most ``deadline_low`` of
  its budget when there is a reading) for ``calm_seconds``, and not within
  ``cooldown_seconds`` of its last move. The gap between high and low marks plus
  the two waits is the hysteresis that keeps a monitor from flapping; a monitor
  pushed back up within a cooldown of coming down (a bounce) waits twice as long
  before the next descent. Moving *up* is never delayed but for that
  ``deadline_wait``: the robot's deadlines come first.
* **Start** (:func:`start_on`, the one rule for it: the orchestrator's rounds and the
  operator's new Monitors both ask it): a monitor active on no handler (handlers
  started with ``--active none``) starts on the least loaded handler of its home tier
  (``placement.tier``, default the lowest), or of the nearest tier above that has one
  and that ``placement.maxLatencyMs`` allows; never below its home tier. Least loaded:
  not under pressure first, then the lowest CPU, then the name.
* ``placement.migrate: pinned`` never moves, but home: one that started above its home
  tier (none of its handlers there then) moves where it would start now once that is
  lower, in one move; ``placement.maxLatencyMs`` forbids tiers whose latency from the
  robot is larger.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field

from edgerv.core.documents import Placement
from edgerv.core.fair_share import fill
from edgerv.core.planner import EdgeState, MonitorCost, PlannerConfig, plan_moves
from edgerv.core.robots import may_host


@dataclass(frozen=True)
class MonitorLoad:
    active: bool
    events_per_second: float = 0.0
    migration_wanted: bool = False
    in_handoff: bool = False  # being moved right now (by anyone): placed, leave it alone
    cpu: float | None = None  # cores its handler spends on it (measured); None: not yet known
    topics: tuple[str, ...] = ()  # the topics it reads


@dataclass(frozen=True)
class DeadlineReading:
    """The robot's real-time task on a handler's machine (``--deadline``): its budget and
    the 95th percentile of its makespans over the window, in seconds."""

    budget: float
    p95: float | None  # None: no makespan in the window
    count: int  # makespans in the window
    misses: int = 0  # of those, longer than the budget
    last: float | None = None  # the newest makespan in the window (None: none)
    # the 95th percentile of the outputs' service times: their makespans less the waits
    # behind the previous output (core.deadline); None: not reported
    service_p95: float | None = None


@dataclass(frozen=True)
class HandlerReport:
    name: str
    tier: str
    cpu: float  # the handler process's CPU: seconds a second (1.0 = one core busy; may pass 1)
    ingest_lag: float = 0.0  # seconds
    monitors: Mapping[str, MonitorLoad] = field(default_factory=dict)
    deadline: DeadlineReading | None = None  # None: the handler measures no deadline
    # cores its CPUs leave for verification: what they idle, and what its monitors take
    # (None: not known yet, or its machine does not say)
    headroom: float | None = None
    # the real-time task's CPU seconds per output on its CPUs (None: not known)
    task_work: float | None = None
    robot: str | None = None  # the robot whose node it runs on (None: a shared node)
    # cores each topic its monitors read takes to ingest there (measured), whatever
    # number of monitors read it: freed when the last leaves
    topics: Mapping[str, float] = field(default_factory=dict)
    # ms the robot's messages take from their publication to it (the 95th percentile it
    # measures: the load report's reachMs); None: none reached it yet
    reach_ms: float | None = None

    def active(self) -> list[str]:
        return [m for m, load in self.monitors.items() if load.active]


class PolicyConfigError(ValueError):
    """A policy setting out of range; ``setting`` names the PolicyConfig field."""

    def __init__(self, message: str, setting: str) -> None:
        super().__init__(message)
        self.setting = setting


@dataclass(frozen=True)
class PolicyConfig:
    tiers: tuple[str, ...]  # lowest (closest to the robot) first, e.g. ("edge", "fog", "cloud")
    tier_latency_ms: Mapping[str, float] = field(default_factory=dict)  # from the robot
    cpu_high: float = 0.85
    cpu_target: float = 0.7
    cpu_low: float = 0.5
    lag_high: float = 0.5
    lag_low: float = 0.1
    calm_seconds: float = 30.0
    cooldown_seconds: float = 60.0
    max_moves_down: int = 1  # per decision: come back gently
    # Deadline pressure: p95 makespan / budget at or above deadline_high; calm needs it at
    # or below deadline_low. Under it, shed at least deadline_shed of the movable event load,
    # then leave the deadline alone deadline_wait seconds (the window refills).
    deadline_high: float = 1.0
    deadline_low: float = 0.95
    deadline_shed: float = 0.5
    deadline_wait: float = 2.0
    deadline_min_count: int = 4  # fewer makespans in the window: no information, unless
    # every one of at least deadline_sure_misses missed: were the task's p95 within its
    # budget, a makespan would miss at most 5% of the time, two in a row 0.25% of it
    deadline_sure_misses: int = 2
    # The planner (edgerv.core.planner) sizes deadline moves, up and home, from the
    # monitors' measured costs once every one of a handler's is known; else the rule above.
    # planner_margin: the share of the headroom verification leaves free; planner_seconds:
    # the exact solver's time budget (0: its greedy rule only).
    planner: bool = True
    planner_margin: float = 0.1
    planner_seconds: float = 0.2

    def __post_init__(self) -> None:
        if not self.tiers or len(set(self.tiers)) != len(self.tiers):
            raise ValueError("tiers must be distinct names, lowest first")
        if not self.cpu_low < self.cpu_target < self.cpu_high:
            raise ValueError("need cpu_low < cpu_target < cpu_high")
        if not 0 < self.deadline_low < self.deadline_high:
            raise PolicyConfigError("need 0 < deadline_low < deadline_high", "deadline_low")
        if not 0 < self.deadline_shed <= 1:
            raise PolicyConfigError("need 0 < deadline_shed <= 1", "deadline_shed")
        if not 0 <= self.deadline_wait < float("inf"):
            raise PolicyConfigError("need deadline_wait >= 0 seconds", "deadline_wait")
        if not 1 <= self.max_moves_down <= 100_000:
            raise PolicyConfigError("need 1 <= max_moves_down <= 100000", "max_moves_down")
        if not 0 <= self.planner_margin < 1:
            raise PolicyConfigError("need 0 <= planner_margin < 1", "planner_margin")
        if not 0 <= self.planner_seconds < float("inf"):
            raise PolicyConfigError("need planner_seconds >= 0", "planner_seconds")


def tier_latencies(text: str) -> dict[str, float]:
    """``edge=0,cloud=40``: each tier's latency from the robot in milliseconds, a finite
    number from 0 (:attr:`PolicyConfig.tier_latency_ms`). Raises :class:`ValueError`
    naming the first item that is not NAME=NUMBER."""
    out = {}
    for item in filter(None, (p.strip() for p in text.split(","))):
        key, eq, value = item.partition("=")
        try:
            if not eq or not key.strip() or not 0 <= float(value) < math.inf:
                raise ValueError
        except ValueError:
            raise ValueError(f"'{item}' is not NAME=NUMBER (a number from 0)") from None
        out[key.strip()] = float(value)
    return out


@dataclass(frozen=True)
class Move:
    monitor: str
    source: str  # handler names; "" to start a monitor that runs nowhere
    destination: str
    reason: str
    plan: str = ""  # a planned move: the plan's method and reason, in words


@dataclass
class PolicyMemory:
    """What the policy remembers between decisions."""

    calm_since: dict[str, float] = field(default_factory=dict)  # handler -> calm from
    last_move: dict[str, float] = field(default_factory=dict)  # monitor -> when it moved
    last_down: dict[str, float] = field(default_factory=dict)  # monitor -> when it came down
    bounces: dict[str, int] = field(default_factory=dict)  # monitor -> up soon after down
    # handler -> from when its deadline's window refills after a move that changed what
    # runs on it: monitors shed from it for its deadline (from then), or a batch brought
    # home to it (one deadline_wait later: taking them over, subscribing to their topics
    # again and the events held for them are work on its core for about that long); the
    # orchestrator sets it again when the handoff ends. Its deadline counts again once its
    # window holds makespans measured since (deadline_wait): not the handoff's own.
    deadline_moved: dict[str, float] = field(default_factory=dict)
    # handler -> when a poll after that move first read the loop caught up (its newest
    # makespan within the budget): its window holds the drained backlog's late makespans
    # until deadline_wait after it (deadline_waits)
    deadline_caught_up: dict[str, float] = field(default_factory=dict)
    # handler -> when monitors were last shed from it for its ingest lag: the lag it
    # reports drains only once the handler has caught up with its backlog, so it is not
    # acted on again for deadline_wait (the rounds meanwhile would read the old backlog)
    lag_moved: dict[str, float] = field(default_factory=dict)
    # monitor -> tier -> what it last cost there (cores): a monitor away from home is
    # planned home at the larger of what it cost there and what it costs where it runs
    # now (there it was last read overloaded, in long batches: cheaper a message)
    costs: dict[str, dict[str, float]] = field(default_factory=dict)
    # handler -> topic -> what its ingestion last cost there (cores): a topic no monitor
    # reads there now is planned home at it
    topic_costs: dict[str, dict[str, float]] = field(default_factory=dict)


def is_loaded(h: HandlerReport, c: PolicyConfig) -> bool:
    """Under pressure from its own load: CPU, ingest lag, a monitor that wants to move."""
    return (
        h.cpu >= c.cpu_high
        or h.ingest_lag >= c.lag_high
        or any(m.active and m.migration_wanted for m in h.monitors.values())
    )


def informs(d: DeadlineReading, c: PolicyConfig) -> bool:
    """Whether the window's p95 is information: at least ``deadline_min_count``
    makespans, or fewer that all missed (at least ``deadline_sure_misses``)."""
    return d.count >= c.deadline_min_count or (
        d.count >= c.deadline_sure_misses and d.misses == d.count
    )


def deadline_ratio(h: HandlerReport, c: PolicyConfig) -> float | None:
    """p95 makespan / budget, or None without information (no reading, too few makespans)."""
    d = h.deadline
    if d is None or d.p95 is None or not informs(d, c) or d.budget <= 0:
        return None
    return d.p95 / d.budget


def deadline_at_risk(h: HandlerReport, c: PolicyConfig) -> bool:
    ratio = deadline_ratio(h, c)
    return ratio is not None and ratio >= c.deadline_high


def is_pressured(h: HandlerReport, c: PolicyConfig) -> bool:
    return is_loaded(h, c) or deadline_at_risk(h, c)


def is_calm(h: HandlerReport, c: PolicyConfig) -> bool:
    ratio = deadline_ratio(h, c)
    return (
        h.cpu <= c.cpu_low
        and h.ingest_lag <= c.lag_low
        and not any(m.active and m.migration_wanted for m in h.monitors.values())
        and (ratio is None or ratio <= c.deadline_low)
    )


def still_waits(moved: Mapping[str, float], h: HandlerReport, c: PolicyConfig, now: float) -> float:
    """Seconds until ``h``'s ingest lag (``moved``: PolicyMemory.lag_moved) counts again
    after monitors were moved for it: ``deadline_wait`` after that move; 0 once it has
    passed, or with none."""
    return max(0.0, c.deadline_wait - (now - moved.get(h.name, -math.inf)))


def deadline_moved(memory: PolicyMemory, handler: str, at: float) -> None:
    """Monitors were moved for ``handler``'s deadline, or onto it, ending at ``at``: its
    deadline waits (:func:`deadline_waits`) from then, the loop not caught up yet."""
    memory.deadline_moved[handler] = at
    memory.deadline_caught_up.pop(handler, None)


def deadline_waits(memory: PolicyMemory, h: HandlerReport, c: PolicyConfig, now: float) -> float:
    """Seconds until ``h``'s deadline pressure counts again after monitors were moved
    for it (or onto it): ``deadline_wait`` after that move, and, once a poll has read the
    loop caught up with the backlog the move left (:func:`note_caught_up`), until
    ``deadline_wait`` after that: the window then holds only makespans of outputs that
    did not queue behind the move's. A loop never read caught up counts again after the
    first wait: still late then, the move was not enough. 0 with no move."""
    moved = memory.deadline_moved.get(h.name)
    if moved is None:
        return 0.0
    since = max(moved, memory.deadline_caught_up.get(h.name, -math.inf))
    return max(0.0, c.deadline_wait - (now - since))


def note_caught_up(memory: PolicyMemory, h: HandlerReport, now: float) -> None:
    """The first poll after a move for ``h``'s deadline whose newest makespan is within
    the budget: the loop has caught up with the outputs queued behind late ones."""
    moved, d = memory.deadline_moved.get(h.name), h.deadline
    if (
        moved is not None
        and moved <= now
        and h.name not in memory.deadline_caught_up
        and d is not None
        and d.last is not None
        and d.last <= d.budget
    ):
        memory.deadline_caught_up[h.name] = now


def tier_allowed(tier: str, placement: Placement, c: PolicyConfig) -> bool:
    budget = placement.max_latency_ms
    return budget is None or c.tier_latency_ms.get(tier, 0.0) <= budget


def measured(c: PolicyConfig, handlers: Sequence[HandlerReport]) -> PolicyConfig:
    """``c`` with each tier's latency from the robot as the larger of what ``c`` says
    (``tier_latency_ms``, ``--tier-latency``) and what the tier's handlers measure (their
    ``reach_ms``, the highest of them): ``placement.maxLatencyMs`` holds on the link as
    it is, and what is said holds before anything is measured (a tier none of whose
    handlers reads a topic yet)."""
    merged = dict(c.tier_latency_ms)
    for h in handlers:
        if h.reach_ms is not None and h.reach_ms > merged.get(h.tier, 0.0):
            merged[h.tier] = h.reach_ms
    return c if merged == c.tier_latency_ms else dataclasses.replace(c, tier_latency_ms=merged)


def _shed_enough(
    shed: float, total: float, excess: float, floor: float | None, loaded: bool
) -> bool:
    """Has a handler shed enough (events/s) of its active load ``total``? The CPU's
    ``excess`` share, and under deadline pressure the deadline's ``floor`` too. Before
    any rate is known, load pressure moves everything and the deadline alone nothing."""
    if not total:
        return not loaded
    return shed / total >= excess and (floor is None or shed >= floor)


def _by_load(c: PolicyConfig) -> Callable[[HandlerReport], tuple[bool, float, str]]:
    """The order of the least loaded first: not under pressure, the lowest CPU, the name."""
    return lambda h: (is_pressured(h, c), h.cpu, h.name)


def _least_loaded(
    handlers: Sequence[HandlerReport], tier: str, c: PolicyConfig
) -> HandlerReport | None:
    fit = [h for h in handlers if h.tier == tier and not is_pressured(h, c)]
    return min(fit, key=_by_load(c)) if fit else None


def start_on(
    placement: Placement, handlers: Sequence[HandlerReport], config: PolicyConfig
) -> HandlerReport | None:
    """Where a monitor that runs nowhere starts, among ``handlers`` (those that may run
    it; of a robot's instance, that robot's own and the shared ones): the least loaded
    handler of its home tier (``placement.tier``; the lowest tier
    when it names none, or one not in the tiers), else of the nearest tier above that
    has one and that ``placement.maxLatencyMs`` allows. None: no such handler (never
    below its home tier). ``placement.migrate: pinned`` forbids moves once it runs, not
    where it starts. Tiers' latencies as measured (:func:`measured`)."""
    c = measured(config, handlers)
    home = c.tiers.index(placement.tier) if placement.tier in c.tiers else 0
    for tier in c.tiers[home:]:
        fit = [h for h in handlers if h.tier == tier and may_host(placement.robot, h.robot)]
        if fit and tier_allowed(tier, placement, c):
            return min(fit, key=_by_load(c))
    return None


def _planner_config(c: PolicyConfig) -> PlannerConfig:
    return PlannerConfig(
        high=c.deadline_high,
        low=c.deadline_low,
        margin=c.planner_margin,
        time_budget=c.planner_seconds,
    )


def edge_state(
    h: HandlerReport,
    c: PolicyConfig,
    above: str | None,
    topics: Mapping[str, float] | None = None,
) -> EdgeState | None:
    """``h``'s reading as the planner takes it (``above``: the tier it would move
    monitors to; None: none, its latency 0; ``topics``: what each topic's ingestion
    costs there, default what ``h`` measures now), or None when it has no headroom or
    deadline reading."""
    d = h.deadline
    if h.headroom is None or d is None or d.budget <= 0:
        return None
    return EdgeState(
        headroom=max(0.0, h.headroom),
        deadline=d.budget,
        p95=d.p95 if informs(d, c) else None,
        service_p95=d.service_p95 if informs(d, c) else None,
        cloud_latency_ms=c.tier_latency_ms.get(above, 0.0) if above else 0.0,
        handler_cpu=h.cpu,
        task_work=h.task_work,
        topic_costs=dict(h.topics if topics is None else topics),
    )


def _costs_here(
    h: HandlerReport, pinned: Callable[[str], bool], memory: PolicyMemory
) -> list[MonitorCost] | None:
    """The monitors running on ``h`` (or in a handoff there) as the planner weighs
    them: at what they cost there now, else (just arrived: no rate yet) at what they last
    cost on its tier; None when one's cost is known neither way."""
    out = []
    for m, load in sorted(h.monitors.items()):
        if not (load.active or load.in_handoff):
            continue
        cost = load.cpu if load.cpu is not None else memory.costs.get(m, {}).get(h.tier)
        if cost is None and not load.in_handoff:
            return None
        out.append(
            MonitorCost(
                m,
                "edge",
                cost or 0.0,
                load.events_per_second,
                pinned=pinned(m),
                in_handoff=load.in_handoff,
                topics=load.topics,
            )
        )
    return out


@dataclass
class _Ask:
    """What one handler under pressure would move up to ``destination`` this round."""

    source: HandlerReport
    destination: HandlerReport
    names: list[str]
    reason: str
    why: str  # the plan's method and reason ("": today's rule)
    deadline: bool  # for its deadline: its window must refill after
    lag: bool = False  # for its ingest lag: its backlog must drain after


def _shared_fairly(
    asks: list[_Ask],
    placements: Mapping[str, Placement],
    memory: PolicyMemory,
    c: PolicyConfig,
) -> list[_Ask]:
    """``asks``, those of several robots to one shared handler trimmed to a fair share
    of it (:func:`edgerv.core.fair_share.fill`): when what they ask costs more than the
    room it has below the CPU target, the room is filled least-served robot first, what
    each runs there already counting (nothing there is sent back for it). Only where
    every monitor asked has a measured cost (before, the rule's shares are guesses).
    One robot alone takes what it must shed: a robot's deadline comes before the shared
    handler's target."""
    by_destination: dict[str, list[_Ask]] = {}
    for ask in asks:
        if ask.destination.robot is None and ask.source.robot is not None and ask.names:
            by_destination.setdefault(ask.destination.name, []).append(ask)
    for group in by_destination.values():
        robots = sorted({a.source.robot for a in group if a.source.robot is not None})
        destination = group[0].destination
        asked: dict[str, list[tuple[str, float]]] = {r: [] for r in robots}
        measured = True
        for a in group:
            for m in a.names:
                cost = memory.costs.get(m, {}).get(destination.tier, a.source.monitors[m].cpu)
                if cost is None:
                    measured = False
                    break
                asked[str(a.source.robot)].append((f"{a.source.name}\0{m}", cost))
        if len(robots) < 2 or not measured:
            continue
        running: dict[str, float] = {}
        for m, load in destination.monitors.items():
            robot = placements.get(m, Placement()).robot
            if load.active and robot is not None:
                running[robot] = running.get(robot, 0.0) + (load.cpu or 0.0)
        room = max(0.0, c.cpu_target - destination.cpu)
        kept = fill(room, running, asked)
        if kept is None:
            continue
        given = {name for names in kept.values() for name in names}
        for a in group:
            before = len(a.names)
            a.names = [m for m in a.names if f"{a.source.name}\0{m}" in given]
            note = (
                f"{destination.name}'s room ({room:.3f} cores) shared between "
                f"{len(robots)} robots: {len(a.names)} of {before} up"
            )
            a.why = f"{a.why}; {note}" if a.why else note
    return asks


def plan(
    handlers: Sequence[HandlerReport],
    placements: Mapping[str, Placement],
    config: PolicyConfig,
    memory: PolicyMemory,
    now: float,
) -> list[Move]:
    """The moves to make now. Updates ``memory`` as if they are all made. Tiers'
    latencies as measured (:func:`measured`)."""
    c = measured(config, handlers)
    rank = {t: i for i, t in enumerate(c.tiers)}
    for h in handlers:
        if h.tier not in rank:
            raise ValueError(f"handler {h.name} reports tier '{h.tier}', not one of {c.tiers}")
        if is_calm(h, c):
            memory.calm_since.setdefault(h.name, now)
        else:
            memory.calm_since.pop(h.name, None)
        note_caught_up(memory, h, now)
    for h in handlers:  # what each monitor costs where it runs (planned home at it)
        for m, load in h.monitors.items():
            if load.active and load.cpu is not None:
                memory.costs.setdefault(m, {})[h.tier] = load.cpu
        memory.topic_costs.setdefault(h.name, {}).update(h.topics)
    moves: list[Move] = []
    moved: set[str] = set()

    # Start: a monitor that runs nowhere starts on its home tier (or the nearest one up).
    placed = {
        m for h in handlers for m, load in h.monitors.items() if load.active or load.in_handoff
    }
    for m in sorted({m for h in handlers for m in h.monitors} - placed):
        defining = [h for h in handlers if m in h.monitors]
        start = start_on(placements.get(m, Placement()), defining, c)
        if start is not None:
            moves.append(Move(m, "", start.name, "start"))
            moved.add(m)
            memory.last_move[m] = now

    # being moved right now (by anyone: another driver, the operator, an earlier round)
    in_handoff = {m for h in handlers for m, load in h.monitors.items() if load.in_handoff}

    # Home: a monitor that runs above where it would start now goes there, in one move,
    # when it is pinned (it started above its home tier, which had no handler then;
    # pinned, it is never moved otherwise) or its tier is now too far for its
    # placement.maxLatencyMs (the tier's measured latency grew past it: reason latency).
    for h in sorted(handlers, key=lambda h: h.name):
        for m in sorted(h.active()):
            p = placements.get(m, Placement())
            pinned = p.migrate == "pinned"
            if m in moved or m in in_handoff:
                continue
            if not pinned and tier_allowed(h.tier, p, c):
                continue
            home = start_on(p, [b for b in handlers if b is not h and m in b.monitors], c)
            if home is not None and rank[home.tier] < rank[h.tier]:
                moves.append(Move(m, h.name, home.name, "pinned home" if pinned else "latency"))
                moved.add(m)
                memory.last_move[m] = now

    def movable(name: str, tier: str, to: HandlerReport) -> bool:
        p = placements.get(name, Placement())
        return (
            p.migrate == "auto"
            and tier_allowed(tier, p, c)
            and may_host(p.robot, to.robot)
            and name not in moved
            and name not in in_handoff
        )

    def held(name: str) -> bool:
        """Never moved by a plan: pinned, or moved (started) already this round."""
        return placements.get(name, Placement()).migrate == "pinned" or name in moved

    def latency_of(name: str) -> float | None:
        return placements.get(name, Placement()).max_latency_ms

    def plan_up(h: HandlerReport, up: str) -> tuple[tuple[str, ...], str] | None:
        """The planner's monitors to move up from ``h`` for its deadline, or None when
        it cannot plan (no headroom or reading, a cost not known yet)."""
        state = edge_state(h, c, up, memory.topic_costs.get(h.name))
        here = _costs_here(h, held, memory)
        if state is None or state.p95 is None or here is None:
            return None
        here = [dataclasses.replace(m, max_latency_ms=latency_of(m.name)) for m in here]
        planned = plan_moves(here, state, _planner_config(c))
        return planned.up, f"{planned.method}: {planned.reason}"

    # Up: relieve each handler under pressure. What each asks of a shared handler is
    # given once all have asked: the robots share its room (_shared_fairly).
    asks: list[_Ask] = []
    for h in sorted(handlers, key=lambda h: (rank[h.tier], h.name)):
        loaded = is_loaded(h, c)
        deadline = deadline_at_risk(h, c) and not deadline_waits(memory, h, c, now)
        if not (loaded or deadline) or rank[h.tier] + 1 >= len(c.tiers):
            continue
        up = c.tiers[rank[h.tier] + 1]
        # up to a shared handler, or one of the same robot's: it may run all of h's
        above = [b for b in handlers if b.robot is None or b.robot == h.robot]
        destination = _least_loaded(above, up, c)
        if destination is None:
            continue
        planned = plan_up(h, up) if deadline and not loaded and c.planner else None
        if planned is not None:  # the deadline alone, every cost known: one planned batch
            names, why = planned
            asks.append(_Ask(h, destination, list(names), "deadline", why, True))
            continue
        candidates = [m for m in h.active() if movable(m, up, destination)]
        # those that want to migrate first; then what frees most per millisecond added
        added = c.tier_latency_ms.get(up, 0.0) - c.tier_latency_ms.get(h.tier, 0.0)
        candidates.sort(
            key=lambda m: (
                not h.monitors[m].migration_wanted,
                -h.monitors[m].events_per_second / (1.0 + max(0, added)),
                m,
            )
        )
        total = sum(load.events_per_second for load in h.monitors.values() if load.active)
        excess = max(0.0, (h.cpu - c.cpu_target) / h.cpu) if h.cpu > 0 else 0.0
        # an ingest that lags with CPU to spare (a CPU budget it cannot keep up under, a
        # core the real-time task takes) says nothing of how much to shed: at least
        # deadline_shed of the movable load, as for the deadline, then its wait
        lagging = h.ingest_lag >= c.lag_high and not still_waits(memory.lag_moved, h, c, now)
        # under deadline pressure, at least deadline_shed of the movable load (busiest first)
        movable_load = sum(h.monitors[m].events_per_second for m in candidates)
        floor = c.deadline_shed * movable_load if deadline or lagging else None
        shed = 0.0
        chosen: list[str] = []
        for m in candidates:
            load = h.monitors[m]
            if not load.migration_wanted and _shed_enough(shed, total, excess, floor, loaded):
                break
            chosen.append(m)
            shed += load.events_per_second
        reason = "deadline" if deadline else "pressure"
        asks.append(_Ask(h, destination, chosen, reason, "", deadline, lagging))
    for ask in _shared_fairly(asks, placements, memory, c):
        for m in ask.names:
            moves.append(Move(m, ask.source.name, ask.destination.name, ask.reason, ask.why))
            moved.add(m)
            memory.last_move[m] = now
            if now - memory.last_down.get(m, float("-inf")) < c.cooldown_seconds:
                memory.bounces[m] = memory.bounces.get(m, 0) + 1  # it came down too soon
        if ask.names and ask.deadline:
            deadline_moved(memory, ask.source.name, now)  # its window must refill first
        if ask.names and ask.lag:
            memory.lag_moved[ask.source.name] = now  # its backlog must drain first

    # monitors planned home this round, per destination: they count there for the next plan
    coming: dict[str, list[MonitorCost]] = {}

    def plan_home(
        b: HandlerReport, h: HandlerReport, candidates: list[str]
    ) -> tuple[tuple[str, ...], str] | None:
        """The planner's monitors of ``candidates`` (on ``h``) to bring home to the calm
        ``b``, or None when it cannot plan (no headroom or reading there, a cost there not
        known yet)."""
        # a topic read below now at what it costs there; else at what it last cost there,
        # else at what it costs where its monitors run now
        topics = {**h.topics, **memory.topic_costs.get(b.name, {}), **b.topics}
        state = edge_state(b, c, h.tier, topics)
        here = _costs_here(b, held, memory)
        if state is None or state.p95 is None or here is None:
            return None
        away = []
        for m in candidates:
            # at the larger of what it last cost there and what it costs now: there it was
            # last read overloaded (why it moved), in long batches that under-read it
            there, current = memory.costs.get(m, {}).get(b.tier), h.monitors[m].cpu
            known = [x for x in (there, current) if x is not None]
            cost = max(known) if known else None
            if cost is not None:  # (its cost known nowhere yet: it waits a round)
                load = h.monitors[m]
                away.append(
                    MonitorCost(
                        m,
                        "cloud",
                        cost,
                        load.events_per_second,
                        latency_of(m),
                        topics=load.topics,
                    )
                )
        planned = plan_moves(here + coming.get(b.name, []) + away, state, _planner_config(c))
        coming.setdefault(b.name, []).extend(
            dataclasses.replace(a, tier="edge") for a in away if a.name in planned.down
        )
        return planned.down, f"{planned.method}: {planned.reason}"

    # Down: bring monitors above their home tier back one tier, below a calm handler.
    budget = c.max_moves_down
    for h in sorted(handlers, key=lambda h: (-rank[h.tier], h.name)):
        if rank[h.tier] == 0:
            continue
        down = c.tiers[rank[h.tier] - 1]
        below = [
            b
            for b in handlers
            if b.tier == down
            and b.name in memory.calm_since
            and now - memory.calm_since[b.name] >= c.calm_seconds
        ]
        if not below:
            continue
        # each monitor home to the least loaded calm handler below that may run it (a
        # robot's instance: its robot's own, or a shared one): one batch per destination
        homes: dict[str, tuple[HandlerReport, list[str]]] = {}
        for m in sorted(h.active()):
            p = placements.get(m, Placement())
            fit = [b for b in below if may_host(p.robot, b.robot)]
            if rank[h.tier] <= rank.get(p.tier or "", 0) or not fit:
                continue
            destination = min(fit, key=_by_load(c))  # calm: none under pressure
            if not movable(m, down, destination):
                continue
            wait = c.cooldown_seconds * 2 ** memory.bounces.get(m, 0)
            if now - memory.last_move.get(m, float("-inf")) < wait:
                continue
            homes.setdefault(destination.name, (destination, []))[1].append(m)
        for destination, candidates in homes.values():
            planned = plan_home(destination, h, candidates) if c.planner else None
            if planned is not None:  # what fits the headroom and the deadline: one batch
                names, why = planned
                for m in names:
                    moves.append(Move(m, h.name, destination.name, "calm below", why))
                    moved.add(m)
                    memory.last_move[m] = memory.last_down[m] = now
                if names:  # its deadline counts again once the handoff has settled
                    deadline_moved(memory, destination.name, now + c.deadline_wait)
                continue
            for m in candidates:
                if budget <= 0:
                    break
                moves.append(Move(m, h.name, destination.name, "calm below"))
                moved.add(m)
                memory.last_move[m] = memory.last_down[m] = now
                budget -= 1
    return moves
