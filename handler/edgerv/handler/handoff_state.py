"""A monitor's handoff state on one handler, and the steps that change it.

docs/protocol.md describes the handoff; this is its state machine on each side, in one
place. A monitor that is in no handoff has the state ``None`` (it runs here, or is
defined here and idle).

Sender (H1)::

    None --hold--> SENDING --release--> RELEASED --commit--> None (let go: it runs there)
                   SENDING --abort/expire--> None (resumed here)
                   RELEASED --abort--> None (resumed here from the snapshot it sent)

Receiver (H2)::

    None --receive--> RECEIVING --adopt--> None (runs here)
                      RECEIVING --abort/expire--> None (dropped: it never ran here)

Only SENDING evaluates nothing yet buffers everything (the monitor is still this
handler's); RELEASED and RECEIVING are the other handler's until the handoff settles.
"""

from __future__ import annotations

from enum import StrEnum


class HandoffState(StrEnum):
    SENDING = "sending"  # H1 holds it: buffers its events, evaluates none
    RELEASED = "released"  # H1 sent its snapshot; keeps it, holding, until H2 confirms
    RECEIVING = "receiving"  # H2 buffers its events until the snapshot comes


# Every change a step may make: (from, to). None: in no handoff.
TRANSITIONS: frozenset[tuple[HandoffState | None, HandoffState | None]] = frozenset(
    {
        (None, HandoffState.SENDING),  # hold
        (HandoffState.SENDING, HandoffState.RELEASED),  # release
        (HandoffState.SENDING, None),  # abort, expiry: resumed
        (HandoffState.RELEASED, None),  # commit (let go), or abort (resumed)
        (None, HandoffState.RECEIVING),  # receive
        (HandoffState.RECEIVING, None),  # adopt, or abort/expiry (dropped)
    }
)


class HandoffStateError(AssertionError):
    """A step tried a change the state machine does not have: a bug, not bad input."""


def check_transition(old: HandoffState | None, new: HandoffState | None) -> None:
    if (old, new) not in TRANSITIONS:
        raise HandoffStateError(f"no handoff step goes from {old} to {new}")
