"""A topic's atoms computed once a message, for the plain monitors that read it.

A plain monitor (:attr:`edgerv.core.pipeline.MonitorRuntime.plain`: no clock, past
operator, wide letter or optional) makes its letter from its atoms alone. Many monitors
of one topic compare its fields with the same constants (the case study's 130 monitors of
``/odom`` evaluate 416 atoms a message, 45 of them distinct), so a topic keeps its
distinct atoms (:class:`TopicAtoms`) and computes each once a message; each monitor's
:class:`PlainPlan` says which of them are its placeholders. An atom that also reads a
signal of another topic is the monitor's own, evaluated on its signal values as before.

The letter is the one the monitor's own atom functions give after the message's
updates: an atom over the message's fields alone reads the same values either way.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

from edgerv.core.monitor import CompiledMonitor

# (left field, right field or None: the constant, comparison, the constant's type, constant)
AtomKey = tuple[int, int | None, Callable[[Any, Any], Any], type, Any]


class PlainPlan(NamedTuple):
    """What one message of a topic does to a plain monitor's signals and letter."""

    updates: tuple[tuple[int, int], ...]  # (signal index, field index): the values it sets
    keep: int  # the letter's bits it leaves: those of atoms that read none of them
    shared: tuple[tuple[int, int], ...]  # (index in the topic's atoms, the atom's bit)
    own: tuple[int, ...]  # atoms that read another topic's signal too: by their functions


class TopicAtoms:
    """One topic's distinct atoms over its fields (those of its plain monitors)."""

    def __init__(self) -> None:
        self.index: dict[AtomKey, int] = {}
        self.reads: list[tuple[int, int | None, Callable[[Any, Any], Any], Any]] = []

    def add(self, key: AtomKey) -> int:
        at = self.index.get(key)
        if at is None:
            at = self.index[key] = len(self.reads)
            left, right, compare, _, const = key
            self.reads.append((left, right, compare, const))
        return at

    def truths(self, values: Sequence[Any]) -> list[Any]:
        """Each atom's truth on a message's field values (truthy or not)."""
        return [
            compare(values[left], const if right is None else values[right])
            for left, right, compare, const in self.reads
        ]


def plain_plan(
    atoms: TopicAtoms, monitor: CompiledMonitor, pairs: tuple[tuple[int, int], ...]
) -> PlainPlan:
    """The plan of a plain ``monitor`` whose signals ``pairs`` (signal index, field index)
    a message of the topic of ``atoms`` updates; its atoms over them added to ``atoms``."""
    field_of = dict(pairs)
    reads = {r.bit: r for r in monitor.reads}
    bits = dict.fromkeys(a for s, _ in pairs for a in monitor.atoms_of_signal[s])
    keep = (1 << monitor.letter_bits) - 1
    shared: list[tuple[int, int]] = []
    own: list[int] = []
    for bit in bits:
        keep &= ~(1 << bit)
        r = reads[bit]
        if r.left in field_of and (r.right is None or r.right in field_of):
            right = None if r.right is None else field_of[r.right]
            key = (field_of[r.left], right, r.compare, type(r.const), r.const)
            shared.append((atoms.add(key), 1 << bit))
        else:
            own.append(bit)
    return PlainPlan(pairs, keep, tuple(shared), tuple(own))
