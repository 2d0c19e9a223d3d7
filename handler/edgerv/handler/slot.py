"""One monitor on one handler: its definition, its runtime when active, its counters and
its handoff's state (the steps that change it are in :mod:`edgerv.handler.handoff_steps`)."""

from __future__ import annotations

from dataclasses import dataclass, field

from edgerv.core.handoff import Snapshot
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import MonitorRuntime, Verdict
from edgerv.handler.handoff_state import HandoffState

RECEIVING, RELEASED = HandoffState.RECEIVING, HandoffState.RELEASED


@dataclass
class MonitorSlot:
    """One monitor of this handler: its definition and, when active, its runtime."""

    compiled: CompiledMonitor
    _runtime: MonitorRuntime | None = field(default=None, repr=False)
    admitted: int = 0  # events taken: those the engine admitted, and its past runtimes'
    dropped: int = 0
    verdicts: dict[str, int] = field(default_factory=lambda: {"violated": 0, "satisfied": 0})
    last_verdict: Verdict | None = None  # the newest this handler reached
    pending_since: float | None = None  # when the event buffer got its oldest event
    full_since: float | None = None  # when the buffer rose above HIGH_WATER
    migration_wanted: bool = False
    capacity: int = field(init=False)
    epoch: int = 0  # the newest handoff this handler took part in, for this monitor
    handoff: HandoffState | None = None  # its handoff state here (handoff_state.py)
    released: Snapshot | None = None  # H1: the snapshot it sent, until the handoff commits
    first_stamps: dict[str, int] = field(default_factory=dict)  # H2: first stamp per topic
    # H2: per topic without a message yet, since when (wall ns) its subscription has been
    # matched with every publisher of the topic (the cut's stamp for a silent topic)
    vouched: dict[str, int] = field(default_factory=dict)
    quiet: tuple[str, ...] = ()  # H2: the topics the cut it reported vouched for
    cut_known: tuple[int, float] | None = None  # H1: the cut, and when it first heard of it
    waiting_on: tuple[str, ...] = ()  # H1: the topics its release last waited for
    held_at: float = 0.0  # H1: when it began to hold
    peer: str | None = None  # H1: the receiver, as the driver named it (to settle with)
    handoff_since: float = 0.0  # when it entered its handoff state
    # H2: the epochs of the handoffs it adopted (the newest ADOPTIONS_KEPT), and the newest
    # one forgotten since: a settle may ask about a handoff after a newer one (see abort)
    adopted: list[int] = field(default_factory=list)
    forgotten: int = 0
    prehold: int = 0  # H1: events buffered before the hold, not yet compressed (see hold)
    # spec.onViolation, done here: reactions done, failed, and why the newest failed (None:
    # it was done)
    moved_in: int = 0  # handoffs that moved it here (adopted), since it was defined here
    moved_out: int = 0  # and away from here (committed)
    reactions: int = 0
    reaction_failures: int = 0
    reaction_problem: str | None = None

    @property
    def name(self) -> str:
        return self.compiled.name

    @property
    def runtime(self) -> MonitorRuntime | None:
        return self._runtime

    @runtime.setter
    def runtime(self, runtime: MonitorRuntime | None) -> None:
        old = self._runtime
        if old is not None:  # the events it took, kept in the count
            self.admitted += old.taken
            old.taken = 0
        self._runtime = runtime

    @property
    def events(self) -> int:
        """The events this handler took for it since it was defined here: those the engine
        admitted and those its runtime's plain step took (MonitorRuntime.taken)."""
        rt = self._runtime
        return self.admitted + (rt.taken if rt is not None else 0)

    def __post_init__(self) -> None:
        self.capacity = self.compiled.spec.buffer_capacity

    @property
    def active(self) -> bool:
        """The monitor is this handler's: it runs here, or is paused here for a handoff."""
        return self.runtime is not None and self.handoff not in (RECEIVING, RELEASED)
