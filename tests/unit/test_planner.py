"""The deadline planner (edgerv.core.planner, issue 37): its plans are the optimum an
exhaustive search finds on small instances; it never plans a pinned monitor, one whose
maxLatencyMs the cloud exceeds, or one in a handoff; it never plans both ways; up frees
the need when the movable monitors can, home fits the headroom less its margin; the
greedy rule takes over when the solver has no time; nothing moves inside the band."""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import pytest
from hypothesis import event, given
from hypothesis import strategies as st

from edgerv.core import selection
from edgerv.core.planner import (
    MICRO,
    MILLI,
    EdgeState,
    MonitorCost,
    Plan,
    PlannerConfig,
    Tier,
    microcores,
    millievents,
    plan_moves,
)
from kit.counts import props

DEADLINE = 0.1  # seconds
CLOUD_MS = 40.0
ROOMY = PlannerConfig(time_budget=5.0)  # a loaded machine solves 12 monitors well within it


def edge(
    headroom: float,
    p95: float | None,
    cloud_ms: float = CLOUD_MS,
    handler: float | None = None,
    work: float | None = None,
    topics: Mapping[str, float] | None = None,
    service: float | None = None,
) -> EdgeState:
    return EdgeState(headroom, DEADLINE, p95, cloud_ms, handler, work, dict(topics or {}), service)


def on(
    tier: Tier,
    name: str,
    cost: float,
    rate: float,
    *,
    max_latency_ms: float | None = None,
    pinned: bool = False,
    in_handoff: bool = False,
    topics: tuple[str, ...] = (),
) -> MonitorCost:
    return MonitorCost(name, tier, cost, rate, max_latency_ms, pinned, in_handoff, topics=topics)


# --- instances: up to 12 monitors, costs and rates already in the planner's units ---


@st.composite
def monitors(draw: st.DrawFn, fewest: int, edge_share: float) -> list[MonitorCost]:
    """``fewest`` to 12 monitors, about ``edge_share`` of them on the edge."""
    count = draw(st.integers(fewest, 12))
    on_edge = draw(st.lists(st.floats(0, 1), min_size=count, max_size=count))
    one_in = st.sampled_from((False, False, False, False, False, True))
    return [
        MonitorCost(
            f"m{i:02d}",
            "edge" if on_edge[i] < edge_share else "cloud",
            draw(st.integers(0, 400_000)) / MICRO,
            draw(st.integers(0, 2_000_000)) / MILLI,
            draw(st.sampled_from((None, None, 5.0, 40.0, 100.0))),
            pinned=draw(one_in),
            in_handoff=draw(one_in),
            home=draw(st.sampled_from(("edge", "edge", "edge", "cloud"))),
            topics=tuple(draw(st.sets(st.sampled_from(TOPICS), max_size=2))),
        )
        for i in range(count)
    ]


TOPICS = ("/a", "/b", "/c")
# what each topic's ingestion costs on the edge, when known (absent: nothing)
topic_costs = st.dictionaries(
    st.sampled_from(TOPICS), st.integers(0, 200_000).map(lambda u: u / MICRO), max_size=3
)


configs = st.builds(
    lambda max_home, margin: PlannerConfig(max_home=max_home, margin=margin, time_budget=5.0),
    st.sampled_from((None, None, 1, 2, 3)),
    st.sampled_from((0.0, 0.1, 0.25)),
)


@st.composite
def instances(
    draw: st.DrawFn, p95_ms: st.SearchStrategy[int], fewest: int = 0, edge_share: float = 0.5
) -> tuple[list[MonitorCost], EdgeState, PlannerConfig]:
    """Monitors, a reading and a configuration. The headroom is drawn against what is at
    stake: on the way up, 20% to 100% of what runs on the edge is allowed; on the way home,
    what runs there plus -10% to 110% of what is away (so that some fit and some do not)."""
    ms, config, topics = draw(monitors(fewest, edge_share)), draw(configs), draw(topic_costs)
    here = verification(ms, topics)
    away = sum(microcores(m.cost) for m in ms) + sum(map(microcores, topics.values())) - here
    p95 = draw(p95_ms) / 1000
    if p95 >= DEADLINE:
        room = draw(st.integers(20, 100)) * here // 100
    else:
        room = here + draw(st.integers(-10, 110)) * away // 100
    # the handler's whole CPU on the edge, when known: its monitors' and up to 0.3 more
    handler = draw(st.one_of(st.none(), st.integers(0, 300_000).map(lambda b: (here + b) / MICRO)))
    # and the real-time task's CPU per output, when measured: up to 1.2 deadlines' worth
    work = draw(st.one_of(st.none(), st.integers(0, 120).map(lambda p: DEADLINE * p / 100)))
    # and its service times' p95, when reported: 50% to 100% of the makespans'
    service = draw(st.one_of(st.none(), st.integers(50, 100).map(lambda p: p95 * p / 100)))
    headroom = max(0, room) / MICRO / (1 - config.margin)
    state = edge(headroom, p95, handler=handler, work=work, topics=topics, service=service)
    return ms, state, config


AT_RISK = instances(st.integers(100, 150), 4, 0.8)  # ratio 1.0 .. 1.5, most on the edge
CALM = instances(st.integers(0, 95), 4, 0.3)  # ratio 0 .. 0.95, most away
ANY = instances(st.integers(0, 200))


# --- the rules as the module's docstring states them, written out again ---


def charges(topics: Mapping[str, float]) -> dict[str, int]:
    return {t: microcores(g) for t, g in topics.items() if microcores(g) > 0}


def here(ms: Sequence[MonitorCost]) -> list[MonitorCost]:
    """What counts on the edge: what runs there, and what is in a handoff either way."""
    return [m for m in ms if m.tier == "edge" or m.in_handoff]


def verification(ms: Sequence[MonitorCost], topics: Mapping[str, float] | None = None) -> int:
    """The monitors' costs on the edge, and the ingestion of each topic one of them reads."""
    g = charges(topics or {})
    read = {t for m in here(ms) for t in m.topics if t in g}
    return sum(microcores(m.cost) for m in here(ms)) + sum(g[t] for t in read)


def allowed(e: EdgeState, c: PlannerConfig) -> int:
    return microcores(e.headroom * (1 - c.margin))


def sized(e: EdgeState, c: PlannerConfig) -> float:
    """The p95 over the deadline, or the service times' where smaller (no backlog in
    them); late, never below the high mark."""
    ratio = e.ratio
    assert ratio is not None
    served = ratio if e.service_p95 is None else min(ratio, e.service_p95 / e.deadline)
    return served if ratio < c.high else max(served, c.high)


def calm(e: EdgeState, c: PlannerConfig) -> float:
    """Processor sharing: the task's output takes its work W over the 1 - h of the core
    the handler leaves it; W read off the p95 (W = p95 (1 - h): the service times' when
    reported), and when W is measured, the smaller of the two handler CPUs."""
    h = e.handler_cpu
    assert h is not None
    read_off = 1.0 - (1.0 - h) * sized(e, c) / c.low
    if e.task_work is None:
        return read_off
    return min(read_off, 1.0 - e.task_work / (c.low * e.deadline))


def need(ms: Sequence[MonitorCost], e: EdgeState, c: PlannerConfig) -> int:
    v, ratio, h = verification(ms, e.topic_costs), e.ratio, e.handler_cpu
    assert ratio is not None
    if h is None:  # the share of verification by which the p95 is over the calm mark
        shed = math.ceil(v * (1 - c.low / sized(e, c)))
    else:  # the handler's CPU above the calm mark's
        shed = math.ceil(max(0.0, h - calm(e, c)) * MICRO)
    return max(v - allowed(e, c), shed)


def room(ms: Sequence[MonitorCost], e: EdgeState, c: PlannerConfig) -> int:
    h = e.handler_cpu
    fits = allowed(e, c) - verification(ms, e.topic_costs)
    if h is None:
        return fits
    return min(fits, math.floor(max(0.0, calm(e, c) - h) * (1 - c.margin) * MICRO))


def may_go_up(m: MonitorCost, e: EdgeState) -> bool:
    latency_ok = m.max_latency_ms is None or m.max_latency_ms >= e.cloud_latency_ms
    return m.tier == "edge" and not m.pinned and not m.in_handoff and latency_ok


def may_come_home(m: MonitorCost) -> bool:
    return m.tier == "cloud" and m.home == "edge" and not m.pinned and not m.in_handoff


Item = tuple[str, int, int, frozenset[str]]  # name, microcores, millievents, topics


def items(ms: Sequence[MonitorCost]) -> list[Item]:
    return [
        (m.name, microcores(m.cost), millievents(m.events_per_second), frozenset(m.topics))
        for m in ms
    ]


def freed_up(s: Sequence[Item], ms: Sequence[MonitorCost], e: EdgeState) -> int:
    """Moving ``s`` up frees their costs, and each topic's ingestion once no monitor
    that counts on the edge reads it any more."""
    names = {n for n, _, _, _ in s}
    g = charges(e.topic_costs)
    left = {t for m in here(ms) if m.name not in names for t in m.topics}
    gone = {t for _, _, _, ts in s for t in ts if t in g and t not in left}
    return sum(c for _, c, _, _ in s) + sum(g[t] for t in gone)


def taken_home(s: Sequence[Item], ms: Sequence[MonitorCost], e: EdgeState) -> int:
    """Bringing ``s`` home takes their costs, and each topic's ingestion that no monitor
    counting on the edge reads now."""
    g = charges(e.topic_costs)
    read = {t for m in here(ms) for t in m.topics}
    new = {t for _, _, _, ts in s for t in ts if t in g and t not in read}
    return sum(c for _, c, _, _ in s) + sum(g[t] for t in new)


def fewest_then_least_events(
    candidates: list[Item], target: int, ms: Sequence[MonitorCost], e: EdgeState
) -> tuple[int, int] | None:
    """Exhaustively: the smallest (monitors, events) over sets freeing ``target``."""
    for k in range(len(candidates) + 1):
        rates = [
            sum(ev for _, _, ev, _ in s)
            for s in itertools.combinations(candidates, k)
            if freed_up(s, ms, e) >= target
        ]
        if rates:
            return k, min(rates)
    return None


def most_then_most_events(
    candidates: list[Item], room: int, limit: int, ms: Sequence[MonitorCost], e: EdgeState
) -> tuple[int, int]:
    """Exhaustively: the largest (monitors, events) over sets of at most ``limit`` that fit
    ``room``."""
    for k in range(limit, -1, -1):
        rates = [
            sum(ev for _, _, ev, _ in s)
            for s in itertools.combinations(candidates, k)
            if taken_home(s, ms, e) <= room
        ]
        if rates:
            return k, max(rates)
    return 0, 0


# --- the optimum ---


@props(80)
@given(AT_RISK)
def test_up_is_the_optimum_of_an_exhaustive_search(
    instance: tuple[list[MonitorCost], EdgeState, PlannerConfig],
) -> None:
    ms, e, c = instance
    p = plan_moves(ms, e, c)
    event(f"method {p.method}")  # --hypothesis-show-statistics: how many the solver made
    candidates = items([m for m in ms if may_go_up(m, e)])
    if verification(ms, e.topic_costs) == 0 or not candidates:
        assert (p.up, p.down, p.method) == ((), (), "none")
        return
    target = need(ms, e, c)
    assert p.target_microcores == target
    if target == 0:  # at risk, but the handler's CPU is not what makes the task late
        assert (p.up, p.down, p.method) == ((), (), "none")
        return
    best = fewest_then_least_events(candidates, target, ms, e)
    if best is None:  # they cannot free it: all of them go, and the plan says it falls short
        assert p.method == "all" and set(p.up) == {n for n, _, _, _ in candidates}
        assert "short" in p.reason
        return
    assert p.method in ("milp", "all"), p.reason
    assert p.objective == best
    chosen = [i for i in candidates if i[0] in p.up]
    assert p.moved_microcores == freed_up(chosen, ms, e) >= target


@props(80)
@given(CALM)
def test_home_is_the_optimum_of_an_exhaustive_search(
    instance: tuple[list[MonitorCost], EdgeState, PlannerConfig],
) -> None:
    ms, e, c = instance
    p = plan_moves(ms, e, c)
    event(f"method {p.method}")
    candidates = items([m for m in ms if may_come_home(m)])
    fits = room(ms, e, c)
    limit = len(candidates) if c.max_home is None else min(c.max_home, len(candidates))
    best = most_then_most_events(candidates, fits, limit, ms, e)
    assert p.up == ()
    if best[0] == 0:
        assert (p.down, p.method) == ((), "none")
        return
    assert p.method in ("milp", "all"), p.reason
    assert p.objective == best
    home = taken_home([i for i in candidates if i[0] in p.down], ms, e)
    assert p.moved_microcores == home <= fits
    assert verification(ms, e.topic_costs) + home <= allowed(e, c)


def test_up_moves_the_fewest_then_the_fewest_events_where_the_greedy_rule_does_not() -> None:
    ms = [
        on("edge", "a", 0.20, 900),
        on("edge", "b", 0.20, 100),
        on("edge", "c", 0.15, 50),
        on("edge", "d", 0.10, 10),
        on("edge", "e", 0.05, 1),
    ]
    reading = edge(0.5, 0.12)  # 120%: verification 0.70, allowed 0.45: 0.25 to free
    p = plan_moves(ms, reading, ROOMY)
    assert p.target_microcores == 250_000
    # two monitors are the fewest; of the nine pairs that free 0.25, c and d carry 60 ev/s
    assert (p.up, p.method, p.objective) == (("c", "d"), "milp", (2, 60_000))
    assert "proven optimal" in p.reason
    greedy = plan_moves(ms, reading, PlannerConfig(time_budget=0))
    assert (greedy.up, greedy.method, greedy.objective) == (("a", "b"), "greedy", (2, 1_000_000))
    assert "no time budget for the solver" in greedy.reason


def test_home_brings_the_most_that_fit_then_the_most_events() -> None:
    ms = [
        on("edge", "x", 0.10, 10),
        on("cloud", "a", 0.12, 1000),
        on("cloud", "b", 0.05, 10),
        on("cloud", "c", 0.06, 20),
        on("cloud", "d", 0.07, 500),
        on("cloud", "e", 0.30, 5000),
    ]
    # allowed 0.9 * 0.4 = 0.36, verification 0.10: a room of 0.26; three fit (b, c, d:
    # 0.18), and of the four threes that fit, a, c, d carries the most events/s (0.25 cores)
    p = plan_moves(ms, edge(0.4, 0.05), ROOMY)
    assert p.target_microcores == 260_000
    assert (p.down, p.method, p.objective) == (("a", "c", "d"), "milp", (3, 1_520_000))
    assert p.moved_microcores == 250_000
    greedy = plan_moves(ms, edge(0.4, 0.05), PlannerConfig(time_budget=0))
    assert (greedy.down, greedy.objective) == (("b", "c", "d"), (3, 530_000))
    one = plan_moves(ms, edge(0.4, 0.05), PlannerConfig(max_home=1, time_budget=5.0))
    assert one.down == ("a",)  # e (0.30) does not fit the room; a is the busiest that does


# --- properties over any reading ---


@props(150)
@given(ANY, st.booleans())
def test_a_plan_never_moves_what_it_must_not_and_goes_one_way(
    instance: tuple[list[MonitorCost], EdgeState, PlannerConfig], blind: bool
) -> None:
    ms, e, c = instance
    if blind:  # no deadline signal
        e = edge(e.headroom, None)
    p = plan_moves(ms, e, c)
    by_name = {m.name: m for m in ms}
    assert not (p.up and p.down)
    assert all(may_go_up(by_name[n], e) for n in p.up)  # never pinned, latency, handoff
    assert all(may_come_home(by_name[n]) for n in p.down)
    assert (p.method == "none") == (not p.up and not p.down)
    ratio = e.ratio
    if ratio is None or c.low < ratio < c.high:  # no signal, or the hysteresis band
        assert p.method == "none"
        assert ("no deadline signal" if ratio is None else "hysteresis") in p.reason
    if p.up:
        movable = sum(microcores(m.cost) for m in ms if may_go_up(m, e))
        assert p.moved_microcores >= min(p.target_microcores, movable)
    if p.down:
        assert verification(ms, e.topic_costs) + p.moved_microcores <= allowed(e, c)
    again = plan_moves(list(reversed(ms)), e, c)  # the order given plays no part
    assert (again.up, again.down, again.method) == (p.up, p.down, p.method)


def test_a_monitor_in_a_handoff_stays_and_counts_on_the_edge() -> None:
    ms = [
        on("cloud", "arriving", 0.20, 100, in_handoff=True),
        on("cloud", "a", 0.10, 100),
        on("cloud", "b", 0.10, 100),
    ]
    # allowed 0.36, less the 0.20 that may be arriving: a room of 0.16, one of a, b fits
    p = plan_moves(ms, edge(0.4, 0.05), ROOMY)
    assert p.target_microcores == 160_000 and len(p.down) == 1
    up = plan_moves([on("edge", "leaving", 0.3, 1, in_handoff=True)], edge(0.1, 0.2), ROOMY)
    assert (up.up, up.method) == ((), "none") and "in a handoff: leaving" in up.reason


def test_pinned_and_latency_held_monitors_stay_and_the_plan_names_them() -> None:
    ms = [
        on("edge", "pin", 0.5, 1, pinned=True),
        on("edge", "near", 0.5, 1, max_latency_ms=10.0),
        on("edge", "free", 0.1, 1),
    ]
    p = plan_moves(ms, edge(0.5, 0.15), ROOMY)  # 1.1 on the edge, 0.45 allowed
    assert (p.up, p.method) == (("free",), "all")
    assert "0.55 cores short" in p.reason
    assert "pinned: pin" in p.reason and "below the cloud's 40 ms: near" in p.reason
    assert plan_moves(ms, edge(0.5, 0.15, cloud_ms=10.0), ROOMY).up == ("free", "near")


# --- the fallback and the hysteresis ---


def test_the_greedy_rule_takes_over_when_the_solver_runs_out_of_time() -> None:
    # rates proportional to costs: the second criterion is a subset sum, which HiGHS does
    # not prove in a microsecond
    ms = [
        on("edge", f"m{i:03d}", (1000 + 37 * i % 1900) / MICRO, (1000 + 37 * i % 1900) / 100)
        for i in range(300)
    ]
    reading = edge(sum(m.cost for m in ms) * 0.7 / 0.9, 0.105)  # 30% of it to free
    p = plan_moves(ms, reading, PlannerConfig(time_budget=1e-6))
    assert p.method == "greedy" and "the solver stopped unproven in 1e-06 s" in p.reason
    assert p.solver_seconds > 0
    by_rule = plan_moves(ms, reading, PlannerConfig(time_budget=0))
    assert (by_rule.up, by_rule.method) == (p.up, "greedy")  # the same rule, deterministic
    assert p.moved_microcores >= p.target_microcores
    # the greedy rule is optimal in the number of monitors: largest cost first
    costs = sorted((microcores(m.cost) for m in ms), reverse=True)
    fewest = next(k for k in range(301) if sum(costs[:k]) >= p.target_microcores)
    assert len(p.up) == fewest


@pytest.mark.parametrize(
    ("p95_ms", "up", "down"),
    [(100, ("a",), ()), (99, (), ()), (96, (), ()), (95, (), ("b",)), (20, (), ("b",))],
)
def test_nothing_moves_inside_the_band(p95_ms: int, up: tuple[str], down: tuple[str]) -> None:
    # the marks: up at 100% or more, home at 95% or less; the headroom is no obstacle
    # either way (0.27 allowed, 0.2 on the edge, 0.01 away)
    ms = [on("edge", "a", 0.2, 10), on("cloud", "b", 0.01, 10)]
    p = plan_moves(ms, edge(0.3, p95_ms / 1000), ROOMY)
    assert (p.up, p.down) == (up, down)
    if not up and not down:
        assert p.method == "none" and "hysteresis" in p.reason


def test_what_comes_home_leaves_the_margin_so_it_does_not_bounce() -> None:
    ms = [on("edge", "a", 0.2, 10), on("edge", "b", 0.2, 10), on("edge", "c", 0.2, 10)]
    first = plan_moves(ms, edge(0.4, 0.12), ROOMY)  # 0.6 on the edge, 0.36 allowed
    assert len(first.up) == 2  # 0.24 to free
    moved = [on("cloud" if m.name in first.up else "edge", m.name, 0.2, 10) for m in ms]
    back = plan_moves(moved, edge(0.4, 0.05), ROOMY)  # calm: 0.16 of room, 0.2 each
    assert (back.down, back.method) == ((), "none") and "none of the 2 away fits" in back.reason
    roomier = plan_moves(moved, edge(0.5, 0.05), ROOMY)  # 0.25 of room: one comes home
    assert len(roomier.down) == 1


# --- input ---


def test_inputs_out_of_range_are_refused() -> None:
    with pytest.raises(ValueError, match="named twice: a"):
        plan_moves([on("edge", "a", 0.1, 1), on("cloud", "a", 0.1, 1)], edge(1.0, 0.2))
    with pytest.raises(ValueError, match="cost"):
        on("edge", "a", -0.1, 1)
    with pytest.raises(ValueError, match="events/s"):
        on("edge", "a", 0.1, math.nan)
    with pytest.raises(ValueError, match="deadline"):
        EdgeState(1.0, 0.0, 0.1, 40.0)
    with pytest.raises(ValueError, match="low < high"):
        PlannerConfig(low=1.0, high=1.0)
    with pytest.raises(ValueError, match="margin"):
        PlannerConfig(margin=1.0)
    with pytest.raises(ValueError, match="time_budget"):
        PlannerConfig(time_budget=math.inf)
    assert isinstance(plan_moves([], edge(1.0, 0.2)), Plan)


def test_the_deadline_is_sized_by_processor_sharing_when_the_handlers_cpu_is_known() -> None:
    """The real-time task shares its core with the handler: its makespan stretches by
    1 / (1 - h). At h = 0.3 and a p95 of 130% of the deadline, bringing it to the calm
    mark (95%) takes h to 1 - 0.7 * 1.3 / 0.95 = 0.042: 0.258 cores to free, where the
    first-order share (27% of the monitors' 0.25 cores) would free 0.068."""
    ms = [on("edge", f"m{i}", 0.05, 10.0) for i in range(5)]  # 0.25 cores of monitors
    known = plan_moves(ms, edge(1.0, 0.13, handler=0.3), ROOMY)
    assert known.target_microcores == math.ceil(0.7 * (1.3 / 0.95 - 1) * MICRO)
    assert len(known.up) == 5  # 0.25 < 0.258: all of them, and the plan says it falls short
    assert known.method == "all" and "short" in known.reason
    unknown = plan_moves(ms, edge(1.0, 0.13), ROOMY)
    assert unknown.target_microcores == math.ceil(250_000 * (1 - 0.95 / 1.3))
    assert len(unknown.up) == 2
    # coming home at a p95 of 50%: by the model, at most 0.7 * (1 - 0.5 / 0.95) * 0.9 = 0.298
    away = [on("cloud", f"c{i}", 0.05, 10.0) for i in range(10)]
    home = plan_moves(away, edge(1.0, 0.05, handler=0.3), ROOMY)
    assert len(home.down) == 5 and home.target_microcores == math.floor(
        0.7 * (1 - 0.5 / 0.95) * 0.9 * MICRO
    )


def test_the_deadline_is_sized_by_the_p95_and_the_measured_work_whichever_asks_more() -> None:
    """Far past its deadline (210%) the p95 read off asks for more than the handler
    has (W = 0.263 (1 - 0.29) = 0.19 s: no share of the core keeps the deadline): all
    move at once, in one handoff, and what fits comes home once the loop is calm. Just
    past it (102%), the task's measured work (0.105 s an output: 1 - 0.105 / (0.95 *
    0.125) = 0.116 cores may stay) asks for more than the p95 (which says 0.16): the
    work followed a change in the task's load that the p95's window has not yet."""
    ms = [on("edge", f"m{i:02d}", 0.01, 10.0) for i in range(20)]  # 0.2 cores of monitors
    far = plan_moves(ms, EdgeState(0.2, 0.125, 0.2628, 40.0, 0.29, 0.1), ROOMY)
    assert len(far.up) == 20 and far.method == "all"
    assert far.target_microcores == math.ceil((0.29 - (1 - 0.71 * 0.2628 / 0.125 / 0.95)) * MICRO)
    near = plan_moves(ms, EdgeState(0.2, 0.125, 0.1275, 40.0, 0.2, 0.105), ROOMY)
    free = 0.2 - (1 - 0.105 / (0.95 * 0.125))
    assert 1 - 0.8 * 1.02 / 0.95 > 1 - 0.105 / (0.95 * 0.125)  # the work asks for more
    assert near.target_microcores == math.ceil(free * MICRO)
    assert len(near.up) == math.ceil(round(free, 6) / 0.01) == 9


def test_a_late_loops_backlog_is_not_read_as_sharing_when_its_service_times_are_known() -> None:
    """The reading above, its outputs queued behind late ones (p95 210%), with their
    service times' p95 reported at 110% (core.deadline: the makespans less the waits
    behind the previous output): read off those, 1 - 0.71 * 1.1 / 0.95 = 0.178 cores may
    stay; by the work 0.158; the one asking more: 0.132 cores to free, 14 of the 20, not
    all. Late with service times under the deadline (90%: the backlog alone is late), the
    plan still frees what brings a p95 at the high mark to the calm mark."""
    ms = [on("edge", f"m{i:02d}", 0.01, 10.0) for i in range(20)]
    queued = plan_moves(ms, EdgeState(0.2, 0.125, 0.2628, 40.0, 0.29, 0.1, {}, 0.1375), ROOMY)
    free = 0.29 - min(1 - 0.71 * 1.1 / 0.95, 1 - 0.1 / (0.95 * 0.125))
    assert queued.target_microcores == math.ceil(free * MICRO)
    assert len(queued.up) == math.ceil(round(free, 6) / 0.01) == 14
    draining = plan_moves(ms, EdgeState(0.2, 0.125, 0.2628, 40.0, 0.29, None, {}, 0.1125), ROOMY)
    free = 0.29 - (1 - 0.71 * 1.0 / 0.95)
    assert draining.target_microcores == math.ceil(free * MICRO)
    assert len(draining.up) == math.ceil(round(free, 6) / 0.01) == 4


def test_what_comes_home_keeps_the_p95_not_the_mean_under_the_calm_mark() -> None:
    """The demo's loop, calm: 0.106 s of work an output, its p95 at 90% of 0.125 s, the
    handler at 0.03 cores. By the work alone the handler may take 1 - 0.106 / (0.95 *
    0.125) = 0.107 cores; read off the p95, which carries the loop's spread, 1 - 0.97 *
    0.9 / 0.95 = 0.081: coming home, the smaller, less the margin."""
    away = [on("cloud", f"c{i:02d}", 0.005, 10.0) for i in range(30)]
    reading = EdgeState(1.0, 0.125, 0.1125, 40.0, 0.03, 0.106)
    p = plan_moves(away, reading, ROOMY)
    fits = (1 - 0.97 * 0.9 / 0.95 - 0.03) * 0.9
    assert p.target_microcores == math.floor(fits * MICRO)
    assert len(p.down) == math.floor(fits / 0.005) == 9


@props(60)
@given(AT_RISK, CALM)
def test_both_exact_methods_agree_whatever_the_number_of_topics(
    at_risk: tuple[list[MonitorCost], EdgeState, PlannerConfig],
    calm: tuple[list[MonitorCost], EdgeState, PlannerConfig],
) -> None:
    """Up to ENUMERATED_TOPICS charged topics the count comes from trying each set of
    them; past it, from an integer program over all of them: the same optimum."""
    for ms, e, c in (at_risk, calm):
        by_sets = plan_moves(ms, e, c)
        with pytest.MonkeyPatch.context() as patch:
            patch.setattr(selection, "ENUMERATED_TOPICS", -1)
            by_program = plan_moves(ms, e, c)
        assert by_program.method == by_sets.method, (by_program.reason, by_sets.reason)
        assert by_program.objective == by_sets.objective
        assert by_program.moved_microcores >= 0


# --- a topic's ingestion: freed by its last reader leaving, paid by its first coming home ---


def test_a_topics_ingestion_makes_its_readers_together_the_fewest_to_move() -> None:
    """/imu's ingestion (0.1 cores) is freed only when all three of its readers leave:
    they free 0.16 cores together, where the two largest monitors free 0.11 (with
    /odom's ingestion) and the largest first take four monitors to free 0.15."""
    ms = [
        on("edge", "odom-1", 0.05, 50, topics=("/odom",)),
        on("edge", "odom-2", 0.05, 50, topics=("/odom",)),
        *(on("edge", f"imu-{i}", 0.02, 200, topics=("/imu",)) for i in range(3)),
    ]
    topics = {"/imu": 0.1, "/odom": 0.01}
    reading = edge(0.2 / 0.9, 0.12, topics=topics)  # 0.16 + 0.11 on the edge, 0.2 allowed
    p = plan_moves(ms, reading, ROOMY)
    assert p.target_microcores == 70_000
    # the fewest: both /odom readers (0.1 and its 0.01) or all of /imu (0.16): two win
    assert (p.up, p.method) == (("odom-1", "odom-2"), "milp")
    assert p.moved_microcores == 110_000
    # 0.15 to free: /odom's two and one /imu reader free 0.13; all of /imu, 0.16
    tighter = plan_moves(ms, edge(0.12 / 0.9, 0.12, topics=topics), ROOMY)
    assert (tighter.up, tighter.objective) == (("imu-0", "imu-1", "imu-2"), (3, 600_000))
    assert tighter.moved_microcores == 160_000
    greedy = plan_moves(ms, edge(0.12 / 0.9, 0.12, topics=topics), PlannerConfig(time_budget=0))
    assert greedy.up == tighter.up and greedy.method == "greedy"  # a topic's readers first


def test_what_comes_home_pays_for_the_topics_it_starts_reading() -> None:
    """Calm, with a room of 0.12 cores: /scan is read on the edge already, /imu is not
    (its ingestion 0.1 cores): the two /scan monitors fit, an /imu one would not."""
    ms = [
        on("edge", "scan-0", 0.05, 20, topics=("/scan",)),
        on("cloud", "imu-0", 0.01, 200, topics=("/imu",)),
        on("cloud", "scan-1", 0.03, 20, topics=("/scan",)),
        on("cloud", "scan-2", 0.03, 20, topics=("/scan",)),
    ]
    reading = edge(0.2 / 0.9, 0.05, topics={"/imu": 0.1, "/scan": 0.03})  # 0.08 on the edge
    p = plan_moves(ms, reading, ROOMY)
    assert p.target_microcores == 120_000
    assert (p.down, p.moved_microcores) == (("scan-1", "scan-2"), 60_000)
    assert plan_moves(ms, reading, PlannerConfig(time_budget=0)).down == p.down


@props(150)
@given(ANY)
def test_the_greedy_rule_frees_the_need_and_fits_the_room_with_topics(
    instance: tuple[list[MonitorCost], EdgeState, PlannerConfig],
) -> None:
    """Without the solver the plan is feasible (not optimal): up, it frees what it says
    and at least the need unless all move; home, what it takes fits the room."""
    ms, e, c = instance
    p = plan_moves(ms, e, PlannerConfig(c.high, c.low, c.margin, c.max_home, time_budget=0))
    assert p.method in ("greedy", "all", "none")
    if p.up:
        chosen = items([m for m in ms if m.name in p.up])
        assert p.moved_microcores == freed_up(chosen, ms, e)
        assert p.method == "all" or p.moved_microcores >= p.target_microcores
    if p.down:
        chosen = items([m for m in ms if m.name in p.down])
        assert p.moved_microcores == taken_home(chosen, ms, e) <= room(ms, e, c)
