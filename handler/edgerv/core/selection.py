"""Which monitors move: the selection problem under the deadline planner (issue 37).

An :class:`Item` is a monitor that may move, in the planner's integer units: its cost
(millionths of a core), its rate (thousandths of an event/s) and the topics it reads. A
topic's ingestion on the edge (the middleware delivering its messages, taking and
decoding them) is a *charge* (:class:`Charges`): it is freed only when every monitor
that reads the topic there leaves, and paid again when the first comes home. Without
charges a monitor's cost is all a move frees; with them, moving all but one of a busy
topic's readers frees none of its ingestion, and the plan that frees the most with the
fewest monitors may be a whole topic's.

* :func:`fewest_freeing`: the fewest items, then the fewest events/s, that free at least
  ``need`` (their costs, plus the charges of the topics all of whose readers are chosen).
* :func:`most_fitting`: the most items (at most ``limit``), then the most events/s, whose
  costs plus the charges of the topics they read fit in ``room``.

Both are solved exactly within a time budget, the count first and then the events/s at
that count (a lexicographic optimum). A selection frees (up) or pays for (home) some set
of the charged topics; with at most ENUMERATED_TOPICS of them, each set is tried, its
count found by sorting (up: that set's readers, then the largest costs; home: of the
items reading no other charged topic, the smallest), and the events/s of the sets with
the best count by SciPy's :func:`scipy.optimize.milp` (HiGHS). With more, both stages
are integer programs over all of them. Without charges there is one set, the empty one:
the count is the greedy rule's. A greedy rule (:func:`greedy_up`, :func:`greedy_home`)
plans when the solver is absent, out of time, or its answer fails the exact check: it
frees the need (fits the room), not proven the fewest (most). Monitors of equal cost,
rate and topics are one integer variable (how many of them), taken by name.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

Method = Literal["milp", "greedy"]


@dataclass(frozen=True)
class Item:
    name: str
    cost: int  # microcores
    events: int  # millievents
    topics: frozenset[str] = frozenset()


@dataclass(frozen=True)
class Charges:
    """Topic charges (microcores). Up: the topics that a selection may free (read on the
    edge by items only); home: those it must pay for (read on the edge by none)."""

    cost: Mapping[str, int]

    def of(self, items: Iterable[Item]) -> frozenset[str]:
        """The charged topics ``items`` read."""
        if not self.cost:
            return frozenset()
        return frozenset(t for i in items for t in i.topics if self.cost.get(t, 0) > 0)


@dataclass(frozen=True)
class Selection:
    chosen: tuple[Item, ...]
    method: Method
    seconds: float = 0.0  # in the solver
    why: str = ""  # method greedy: why not the solver's


def freed(chosen: Iterable[Item], items: Sequence[Item], charges: Charges) -> int:
    """What moving ``chosen`` (of ``items``) up frees: their costs, and the charge of each
    topic none of the others reads."""
    picked = list(chosen)
    names = {i.name for i in picked}
    left = charges.of(i for i in items if i.name not in names)
    return sum(i.cost for i in picked) + sum(
        charges.cost[t] for t in charges.of(picked) if t not in left
    )


def paid(chosen: Iterable[Item], charges: Charges) -> int:
    """What bringing ``chosen`` home costs: their costs, and each charged topic they read."""
    picked = list(chosen)
    return sum(i.cost for i in picked) + sum(charges.cost[t] for t in charges.of(picked))


def _events(items: Iterable[Item]) -> int:
    return sum(i.events for i in items)


# -- greedy rules -------------------------------------------------------------------------


def _largest_first(
    items: Sequence[Item], need: int, charges: Charges, first: Sequence[Item] = ()
) -> list[Item] | None:
    """``first``, then the largest cost first (then fewer events, name) until ``need`` is
    freed; None if all of them do not free it."""
    ahead = {i.name for i in first}
    order = list(first) + sorted(
        (i for i in items if i.name not in ahead), key=lambda i: (-i.cost, i.events, i.name)
    )
    reads = {i.name: charges.of([i]) for i in items} if charges.cost else {}
    readers: dict[str, int] = {}  # charged topic -> its readers not chosen yet
    for topics in reads.values():
        for t in topics:
            readers[t] = readers.get(t, 0) + 1
    chosen: list[Item] = []
    done = 0
    for item in order:
        if done >= need:
            return chosen
        chosen.append(item)
        done += item.cost
        for t in reads.get(item.name, ()):
            readers[t] -= 1
            if not readers[t]:
                done += charges.cost[t]
    return chosen if done >= need else None


def greedy_up(items: Sequence[Item], need: int, charges: Charges) -> list[Item]:
    """The greedy rule up: the largest cost first until ``need`` is freed; with charges,
    also each charged topic's readers first, then the largest: the fewest of these
    (then the fewest events/s). ``need`` must be at most what all of them free."""
    tries = [_largest_first(items, need, charges)]
    for topic in sorted(charges.cost):
        readers = sorted((i for i in items if topic in i.topics), key=lambda i: (-i.cost, i.name))
        if readers:
            tries.append(_largest_first(items, need, charges, readers))
    found = [t for t in tries if t is not None]
    if not found:
        raise ValueError("the items cannot free the need")
    return min(found, key=lambda s: (len(s), _events(s)))


def greedy_home(items: Sequence[Item], room: int, limit: int, charges: Charges) -> list[Item]:
    """The greedy rule home: the smallest cost first (with the charges of the topics it
    would start reading; then more events, name) while it fits ``room``, at most
    ``limit``. Without charges, the most that fit."""
    chosen: list[Item] = []
    topics: set[str] = set()
    used = 0
    if not charges.cost:  # the most that fit: the smallest first, while they fit
        for item in sorted(items, key=lambda i: (i.cost, -i.events, i.name)):
            if len(chosen) >= limit or used + item.cost > room:
                break
            chosen.append(item)
            used += item.cost
        return chosen
    own = {i.name: sum(charges.cost[t] for t in charges.of([i])) for i in items}
    for item in sorted(items, key=lambda i: (i.cost + own[i.name], -i.events, i.name)):
        if len(chosen) >= limit:
            break
        extra = item.cost + sum(charges.cost[t] for t in charges.of([item]) - topics)
        if used + extra > room:
            continue  # (one reading fewer topics may fit still)
        chosen.append(item)
        topics |= charges.of([item])
        used += extra
    return chosen


# -- the exact program --------------------------------------------------------------------


def fewest_freeing(items: Sequence[Item], need: int, charges: Charges, budget: float) -> Selection:
    """The fewest items, then the fewest events/s, freeing at least ``need``. ``need``
    must be at most what all of ``items`` free."""
    greedy = greedy_up(items, need, charges)

    def ok(s: Sequence[Item]) -> bool:
        return freed(s, items, charges) >= need

    return _exact(items, greedy, charges, budget, up=True, bound=need, ok=ok, limit=len(items))


def most_fitting(
    items: Sequence[Item], room: int, limit: int, charges: Charges, budget: float
) -> Selection:
    """The most items (at most ``limit``), then the most events/s, that fit ``room``."""
    greedy = greedy_home(items, room, limit, charges)

    def ok(s: Sequence[Item]) -> bool:
        return paid(s, charges) <= room and len(s) <= limit

    return _exact(items, greedy, charges, budget, up=False, bound=room, ok=ok, limit=limit)


def _better(a: Sequence[Item], b: Sequence[Item], up: bool) -> bool:
    """``a`` at least as good as ``b``: (count, events) lexicographically."""
    ka, kb = (len(a), _events(a)), (len(b), _events(b))
    return ka <= kb if up else ka >= kb


def _exact(
    items: Sequence[Item],
    greedy: list[Item],
    charges: Charges,
    budget: float,
    *,
    up: bool,
    bound: int,
    ok: Callable[[Sequence[Item]], bool],
    limit: int,
) -> Selection:
    def fallback(why: str, seconds: float = 0.0) -> Selection:
        return Selection(tuple(greedy), "greedy", seconds, why)

    if budget <= 0:
        return fallback("no time budget for the solver")
    relevant = Charges({t: g for t, g in charges.cost.items() if g > 0})
    if not solver_ready():
        return fallback("SciPy is not installed (pip install 'edgerv[planner]')")
    started = time.perf_counter()
    topics = sorted(relevant.of(items))
    if len(topics) <= ENUMERATED_TOPICS:
        chosen, why = _by_topic_sets(items, relevant, topics, up, bound, limit, budget)
    else:
        program = _Program(items, relevant, up, bound, limit, budget)
        count, why = program.count(budget)
        chosen = None
        if count is not None:
            left = budget - (time.perf_counter() - started)
            chosen, why = program.events(count, max(left, 1e-6))
    seconds = time.perf_counter() - started
    if chosen is None:
        return fallback(why, seconds)
    if not ok(chosen):
        return fallback("the solver's answer failed the exact check", seconds)
    if not _better(chosen, greedy, up):
        return fallback("the solver's answer is worse than the greedy rule's", seconds)
    return Selection(tuple(chosen), "milp", seconds)


# With at most this many charged topics, the count is found by trying each set of them
# (freed up, or paid home: 2**8 = 256 sorts of the items) and only the events/s need the
# solver; with more, both stages are integer programs.
ENUMERATED_TOPICS = 8


@dataclass(frozen=True)
class _Case:
    """One set of charged topics: those freed (up) or paid (home). ``forced`` must move
    with it (up: every reader of a freed topic); ``k`` more of ``pool`` (the fewest up,
    the most home, by sorting) free at least (fit in) ``bound``."""

    forced: tuple[Item, ...]
    pool: tuple[Item, ...]
    k: int
    bound: int

    @property
    def count(self) -> int:
        return len(self.forced) + self.k


def _cases(
    items: Sequence[Item], charges: Charges, topics: Sequence[str], up: bool, bound: int, limit: int
) -> list[_Case]:
    """Each set of ``topics`` that can be freed with ``need`` (up) or paid within the
    room (home), with the count it gives. Exact: a selection frees (pays) some set of
    topics, and among the selections of that set the count by sorting is the best."""
    order = sorted(items, key=(lambda i: (-i.cost, i.name)) if up else (lambda i: (i.cost, i.name)))
    reads = {i.name: charges.of([i]) for i in items}
    cases = []
    for size in range(len(topics) + 1):
        for chosen in itertools.combinations(topics, size):
            these = set(chosen)
            charge = sum(charges.cost[t] for t in these)
            if up:
                forced = tuple(i for i in order if reads[i.name] & these)
                pool = tuple(i for i in order if not reads[i.name] & these)
                rest = bound - charge - sum(i.cost for i in forced)
                k, done = 0, 0
                while done < rest and k < len(pool):
                    done += pool[k].cost
                    k += 1
                if done < rest:
                    continue  # these topics and all the others do not free the need
                cases.append(_Case(forced, pool, k, rest))
            else:
                room = bound - charge
                if room < 0:
                    continue
                pool = tuple(i for i in order if reads[i.name] <= these)
                k, used = 0, 0
                while k < min(limit, len(pool)) and used + pool[k].cost <= room:
                    used += pool[k].cost
                    k += 1
                cases.append(_Case((), pool, k, room))
    return cases


def _by_topic_sets(
    items: Sequence[Item],
    charges: Charges,
    topics: Sequence[str],
    up: bool,
    bound: int,
    limit: int,
    budget: float,
) -> tuple[list[Item] | None, str]:
    """The lexicographic optimum over :func:`_cases`: the best count, then of the sets
    that give it, the fewest (most) events/s, each set's ``k`` of its pool by the solver
    (bounded: a set whose events/s cannot beat the best found is not solved)."""
    started = time.perf_counter()
    cases = _cases(items, charges, topics, up, bound, limit)
    if not cases:
        return None, "no set of topics frees the need"
    best_count = (min if up else max)(c.count for c in cases)
    tied = [c for c in cases if c.count == best_count]

    def hope(c: _Case) -> int:  # the best events/s this set could give
        rates = sorted(i.events for i in c.pool)
        some = rates[: c.k] if up else rates[len(rates) - c.k :]
        return _events(c.forced) + sum(some)

    tied.sort(key=hope, reverse=not up)
    best: list[Item] | None = None
    for case in tied:
        if best is not None and (
            hope(case) >= _events(best) if up else hope(case) <= _events(best)
        ):
            break  # sorted by hope: none after it can do better
        left = budget - (time.perf_counter() - started)
        if left <= 0:
            return None, f"the solver stopped unproven in {budget:g} s: time limit reached"
        if case.k in (0, len(case.pool)):
            chosen = list(case.pool[: case.k])
        else:
            program = _Program(case.pool, Charges({}), up, case.bound, limit, budget)
            solved, why = program.events(case.k, left)
            if solved is None:
                return None, why
            chosen = solved
        picked = list(case.forced) + chosen
        if best is None or (
            _events(picked) < _events(best) if up else _events(picked) > _events(best)
        ):
            best = picked
    return best, ""


def solver_ready() -> bool:
    """Whether SciPy's solver can be used; the first call loads it (0.4 s), which a
    caller that plans against the clock does before its first plan."""
    try:
        import scipy.optimize  # type: ignore[import-untyped]
        import scipy.sparse  # type: ignore[import-untyped]  # noqa: F401
    except ImportError:
        return False
    return True


class _Program:
    """The integer program over kinds of items (equal cost, rate and topics: one
    variable, how many of them) and one binary variable per charged topic: up, it may be
    1 (freed) only when all of the topic's readers are chosen; home, it must be 1 (paid)
    when any is."""

    def __init__(
        self,
        items: Sequence[Item],
        charges: Charges,
        up: bool,
        bound: int,
        limit: int,
        budget: float,
    ) -> None:
        kinds: dict[tuple[int, int, frozenset[str]], list[Item]] = {}
        for item in sorted(items, key=lambda i: i.name):
            topics = frozenset(t for t in item.topics if t in charges.cost)
            kinds.setdefault((item.cost, item.events, topics), []).append(item)
        self.kinds = kinds
        self.keys = sorted(kinds, key=lambda k: (k[0], k[1], sorted(k[2])))
        self.topics = sorted({t for k in self.keys for t in k[2]})
        self.charges, self.up, self.bound, self.limit = charges, up, bound, limit
        self.budget = budget  # seconds, both stages together

    def _solve(
        self, objective: Sequence[float], count: int | None, budget: float
    ) -> tuple[Any, str]:
        """HiGHS on the program with ``objective`` (minimised), the number of items
        ``count`` (None: at most ``limit``): the variables' values, or None and why."""
        import numpy as np
        from scipy.optimize import Bounds, LinearConstraint, milp
        from scipy.sparse import coo_array

        nk, nt = len(self.keys), len(self.topics)
        row: list[int] = []
        col: list[int] = []
        val: list[float] = []
        lower: list[float] = []
        upper: list[float] = []

        def add(entries: Sequence[tuple[int, float]], low: float, high: float) -> None:
            at = len(lower)
            for j, v in entries:
                row.append(at)
                col.append(j)
                val.append(v)
            lower.append(low)
            upper.append(high)

        costs = [(i, float(k[0])) for i, k in enumerate(self.keys)]
        costs += [(nk + j, float(self.charges.cost[t])) for j, t in enumerate(self.topics)]
        if self.up:  # frees at least the need
            add(costs, float(self.bound), np.inf)
        else:  # fits the room
            add(costs, -np.inf, float(self.bound))
        ones = [(i, 1.0) for i in range(nk)]
        if count is None:
            add(ones, 0.0, float(self.limit))
        else:
            add(ones, float(count), float(count))
        for j, topic in enumerate(self.topics):
            for i, key in enumerate(self.keys):
                if topic in key[2]:
                    n = float(len(self.kinds[key]))
                    if self.up:  # freed only when all of this kind move: n y - x <= 0
                        add([(nk + j, n), (i, -1.0)], -np.inf, 0.0)
                    else:  # paid when any of this kind comes home: x - n y <= 0
                        add([(i, 1.0), (nk + j, -n)], -np.inf, 0.0)
        matrix = coo_array((val, (row, col)), shape=(len(lower), nk + nt)).tocsr()
        high = [float(len(self.kinds[k])) for k in self.keys] + [1.0] * nt
        result = milp(
            np.array(objective, dtype=np.float64),
            integrality=np.ones(nk + nt),
            bounds=Bounds(0, np.array(high, dtype=np.float64)),
            constraints=LinearConstraint(matrix, lower, upper),
            options={"time_limit": budget, "mip_rel_gap": 0.0, "presolve": False},
        )
        if int(result.status) != 0 or result.x is None:
            message = str(result.message).split(".")[0].lower()
            return None, f"the solver stopped unproven in {self.budget:g} s: {message}"
        return result.x, ""

    def count(self, budget: float) -> tuple[int | None, str]:
        """The fewest (up) or most (home) items: the first stage."""
        sign = 1.0 if self.up else -1.0
        objective = [sign] * len(self.keys) + [0.0] * len(self.topics)
        x, why = self._solve(objective, None, budget)
        if x is None:
            return None, why
        return sum(max(0, round(float(v))) for v in x[: len(self.keys)]), ""

    def events(self, count: int, budget: float) -> tuple[list[Item] | None, str]:
        """Of ``count`` items, the fewest (up) or most (home) events/s: the second stage."""
        sign = 1.0 if self.up else -1.0
        objective = [sign * k[1] for k in self.keys] + [0.0] * len(self.topics)
        x, why = self._solve(objective, count, budget)
        if x is None:
            return None, why
        return [
            item
            for key, v in zip(self.keys, x[: len(self.keys)], strict=True)
            for item in self.kinds[key][: max(0, round(float(v)))]
        ], ""
