"""An independent LTL3 reference monitor for differential tests.

It shares nothing with edgerv's synthesis path: it takes *nondeterministic
state-based Büchi automata* of f and of !f (not Spot's 'monitor' translation),
decides per-state emptiness with its own SCC search (not Spot's emptiness
check), and simulates the subset of live states on the fly (no product, no
minimization). A prefix is bad when no live state of A(f) is reachable by it,
good when no live state of A(!f) is.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import spot


def eval_bool(f: Any, letter: int, index: dict[str, int]) -> bool:
    """Evaluate a Spot boolean formula on a letter (bit i = placeholder p<i>)."""
    k = f.kind()
    if k == spot.op_tt:
        return True
    if k == spot.op_ff:
        return False
    if k == spot.op_ap:
        return bool(letter >> index[f.ap_name()] & 1)
    if k == spot.op_Not:
        return not eval_bool(f[0], letter, index)
    if k == spot.op_And:
        return all(eval_bool(g, letter, index) for g in f)
    if k == spot.op_Or:
        return any(eval_bool(g, letter, index) for g in f)
    raise ValueError(f"not a boolean formula: {f}")


class _Buchi:
    def __init__(self, f: Any, names: Sequence[str], alphabet: Sequence[int]) -> None:
        aut = spot.translate(f, "Buchi", "state-based", "small")
        assert aut.prop_state_acc().is_true()
        index = {n: i for i, n in enumerate(names)}
        d = aut.get_dict()
        self.init = aut.get_init_state_number()
        n = aut.num_states()
        self.succ: list[list[tuple[frozenset[int], int]]] = []
        for s in range(n):
            edges = []
            for e in aut.out(s):
                cond = spot.bdd_to_formula(e.cond, d)
                letters = frozenset(x for x in alphabet if eval_bool(cond, x, index))
                if letters:
                    edges.append((letters, e.dst))
            self.succ.append(edges)
        accepting = [aut.state_is_accepting(s) for s in range(n)]
        self.live = self._live_states(accepting)

    def _live_states(self, accepting: list[bool]) -> set[int]:
        """States from which some infinite run visits an accepting state infinitely often."""
        n = len(self.succ)
        graph = [[dst for _, dst in edges] for edges in self.succ]
        index_of, low, on_stack, stack, sccs = {}, {}, set(), [], []
        counter = [0]

        def strong(v: int) -> None:  # Tarjan, iterative enough for small automata
            index_of[v] = low[v] = counter[0]
            counter[0] += 1
            stack.append(v)
            on_stack.add(v)
            for w in graph[v]:
                if w not in index_of:
                    strong(w)
                    low[v] = min(low[v], low[w])
                elif w in on_stack:
                    low[v] = min(low[v], index_of[w])
            if low[v] == index_of[v]:
                comp = set()
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    comp.add(w)
                    if w == v:
                        break
                sccs.append(comp)

        for v in range(n):
            if v not in index_of:
                strong(v)
        good = set()
        for comp in sccs:
            cyclic = len(comp) > 1 or any(v in graph[v] for v in comp)
            if cyclic and any(accepting[v] for v in comp):
                good |= comp
        # backward reachability to the good SCCs
        live = set(good)
        changed = True
        while changed:
            changed = False
            for v in range(n):
                if v not in live and any(w in live for w in graph[v]):
                    live.add(v)
                    changed = True
        return live

    def start(self) -> set[int]:
        return {self.init} & self.live

    def step(self, current: set[int], letter: int) -> set[int]:
        return {
            dst
            for s in current
            for letters, dst in self.succ[s]
            if letter in letters and dst in self.live
        }


class ReferenceMonitor:
    """LTL3 verdicts of formula f (over placeholder names) letter by letter, with reset/halt."""

    def __init__(
        self,
        f: Any,
        names: Sequence[str],
        alphabet: Iterable[int] | None = None,
        halt: bool = False,
    ) -> None:
        letters = list(range(1 << len(names))) if alphabet is None else sorted(set(alphabet))
        self.pos = _Buchi(f, names, letters)
        self.neg = _Buchi(spot.formula.Not(f), names, letters)
        self.halt = halt

    def run(self, letters: Iterable[int]) -> list[tuple[str, int]]:
        """(verdict, 1-based step) for every deciding letter."""
        out: list[tuple[str, int]] = []
        p, n = self.pos.start(), self.neg.start()
        for step, letter in enumerate(letters, start=1):
            p, n = self.pos.step(p, letter), self.neg.step(n, letter)
            verdict = "violated" if not p else "satisfied" if not n else None
            if verdict:
                out.append((verdict, step))
                if self.halt:
                    break
                p, n = self.pos.start(), self.neg.start()
        return out
