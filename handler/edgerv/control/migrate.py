"""The handoff driven from outside: move monitors from a handler to another by their
control APIs (:func:`migrate`), and settle what an interrupted move left held
(:func:`settle`). The steps of docs/protocol.md: the receiver subscribes and holds,
the sender holds, the receiver reports the cut, the sender releases the snapshot, the
receiver adopts it. Any failure before the adoption aborts both sides: the monitors
resume on the sender with nothing lost. When the adoption fails, the receiver says
which monitors it adopted: those stay there, the others resume on the sender. After a
failure the calls are retried up to a timeout more, then the error says where each
monitor runs as the handlers confirmed it, or that it could not confirm it.

``edgerv migrate`` (:mod:`edgerv.control.migrate_command`), ``edgerv orchestrate`` and
the operator drive it.
"""

from __future__ import annotations

import contextlib
import functools
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any, TypeVar

from edgerv.control.client import (
    ApiError,
    HandlerClient,
    HttpError,
    Refused,
    Unreachable,
    Unresolved,
    Untrusted,
    WrongScheme,
)
from edgerv.control.wire import HANDOFF_EXPIRES, CutAnswer
from edgerv.core.handoff import HandoffError, frame_sizes, unbundle


class MigrationFailed(ApiError):
    """The move failed (every other failure of a call to a handler is an ApiError too)."""


class NotMoved(MigrationFailed):
    """Some monitors did not move, and where each one runs is what the handlers answered
    (exit 1): a driver never says "stays" on a guess.

    ``where``: monitor -> the address (``HandlerClient.base``) of the handler running it;
    ``""`` when neither of the two does; None when nothing of this move took effect on
    the sender (it never held the monitor for it) and the listings could not be read:
    the monitor is where it was before."""

    def __init__(self, message: str, where: Mapping[str, str | None]) -> None:
        super().__init__(message)
        self.where = dict(where)


class Unsettled(MigrationFailed):
    """Where some monitors run is not confirmed: a handler did not answer in time (exit 3).
    The sender may hold them (evaluated nowhere) until it does. Running the same
    migration again settles them (:func:`settle`), as ``edgerv orchestrate`` does.

    ``names``: the monitors concerned; ``silent``: the handlers that did not answer."""

    def __init__(self, message: str, names: Sequence[str] = (), silent: Sequence[str] = ()):
        super().__init__(message)
        self.names, self.silent = list(names), list(silent)


class Held(Unsettled):
    """The sender holds some of the monitors for an earlier, interrupted handoff:
    :func:`migrate` settles that one first (unsettled if it cannot)."""


T = TypeVar("T")

# A receiver's answers to ``abort`` after a release (Engine.handoffs.abort): it adopted the monitor
# (runs it now, or moved it on since), or it never will; any other leaves it held.
ADOPTED = ("active", "adopted")
NOT_ADOPTED = ("dropped", "nothing to undo", "gone")
RUNS = ("resumed", "active")  # a sender's answers to ``abort``: it runs the monitor (again)
UNDEFINED = "not defined"  # a handler without that monitor (its abort refused that one)
UNAUTHORIZED = "not authorized"  # a handler that refuses the token: it acted on no call
DOWN = "down"  # its port refuses connections: it runs nothing
# A call that failed so that it reached no handler: a setting to fix (the scheme, the CA,
# the host's name), not an answer that may have been lost.
NOT_SENT: tuple[type[ApiError], ...] = (WrongScheme, Untrusted, Unresolved)


def _cut_answer(side: HandlerClient, raw: bytes, names: Sequence[str]) -> CutAnswer:
    """The cut step's answer, checked: a cut (integer nanoseconds, or null: not yet) for
    every monitor asked about, and the topics it vouched for (lists of names)."""
    answer = side.json("the cut", raw)
    cuts = answer.get("cuts") if isinstance(answer, dict) else None
    quiet = answer.get("quiet", {}) if isinstance(answer, dict) else None
    if (
        not isinstance(cuts, dict)
        or set(cuts) != set(names)
        or not all(c is None or (isinstance(c, int) and not isinstance(c, bool))
                   for c in cuts.values())
        or not isinstance(quiet, dict)
        or not all(isinstance(q, list) and all(isinstance(t, str) for t in q)
                   for q in quiet.values())
    ):  # fmt: skip
        raise MigrationFailed(f"{side.base} answered the cut with {raw[:200]!r}: not a cut")
    return CutAnswer(cuts=cuts, quiet=quiet)


def _retry(deadline: float, call: Callable[[], T]) -> T:
    """Repeat a call that failed on the network (every step is idempotent) until the deadline."""
    while True:
        try:
            return call()
        except Unreachable:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.1)


@dataclass
class Moved:
    seconds: float  # from the request to the monitors active on the destination
    snapshot_bytes: int  # what crossed for the monitors' state and buffered letters
    letters: int  # buffered letters (events) moved
    header_bytes: int  # of snapshot_bytes, the per-monitor headers (the constant part)
    steps: dict[str, float]  # seconds from the request to the end of each step
    # ran on the destination already (an earlier handoff, settled now, or before this one)
    already: list[str] = field(default_factory=list)
    note: str = ""  # what is left to tidy up (a sender that did not confirm it let go)


def migrate(
    source: HandlerClient,
    destination: HandlerClient,
    monitors: Sequence[str],
    timeout: float = 30.0,
    grace: float = 1.0,
    after_release: Callable[[], None] | None = None,
) -> Moved:
    """Move ``monitors`` (one handoff, one epoch), or say where they run instead.

    Up to the release, any failure aborts both sides: the monitors resume on the
    source. After it, the destination's adoption decides who owns each monitor
    (docs/protocol.md, "Failures"): adopted -> the source commits (lets go); not
    adopted, or the destination down (its port refuses) -> the destination is
    fenced and the source resumes from the snapshot and the events it kept. Either
    way the calls are retried up to ``timeout`` seconds more. Raises NotMoved with
    where each monitor runs as the handlers confirmed it, or Unsettled when one did
    not answer (the source keeps holding what the destination may have adopted).
    Monitors the source still holds from an interrupted handoff are settled first,
    then moved. (``after_release`` is a seam for tests that break things then.)
    """
    names = list(monitors)
    try:
        return _migrate(source, destination, names, timeout, grace, after_release)
    except Held as exc:
        held = exc.names
    # Some of them are still held from an interrupted handoff: settle that one, then
    # move what came back to the source.
    started = time.monotonic()
    moved = settle(source, held, started + timeout)
    here = moved.get(destination.base, [])
    gone = {n: p for p, group in moved.items() if p != destination.base for n in group}
    if gone:
        where: dict[str, str | None] = {n: None for n in names}
        where.update({n: source.base for n in held if n not in gone})  # resumed there
        where.update({n: destination.base for n in here})
        where.update({n: "" if "moved them on" in p else p for n, p in gone.items()})
        said = "; ".join(f"{n} to {p}" for n, p in gone.items())
        raise NotMoved(
            f"{_say(where, source, destination)} (an earlier handoff moved {said})", where
        )
    rest = [n for n in names if n not in here]
    if not rest:
        seconds = time.monotonic() - started
        return Moved(seconds, 0, 0, 0, {"settle": seconds}, already=here)
    try:
        result = _migrate(source, destination, rest, timeout, grace, after_release)
    except NotMoved as exc:
        where = {**exc.where, **dict.fromkeys(here, destination.base)}
        raise NotMoved(f"{_say(where, source, destination)}: {exc}", where) from None
    result.already += here
    return result


def _migrate(
    source: HandlerClient,
    destination: HandlerClient,
    names: list[str],
    timeout: float,
    grace: float,
    after_release: Callable[[], None] | None,
) -> Moved:
    epoch = time.time_ns()
    started = time.monotonic()
    deadline = started + timeout
    per_call = min(10.0, timeout)

    def step(side: HandlerClient, name: str, **body: Any) -> tuple[int, bytes]:
        timeout = per_call + float(body.get("wait", 0.0))
        return side.handoff(name, epoch, body.pop("monitors", names), timeout, **body)

    steps: dict[str, float] = {}

    def mark(name: str) -> None:
        steps[name] = time.monotonic() - started

    reached = True  # whether the hold may have reached the source
    try:
        # 2a and 2b at once: the receiver's subscription (and its DDS matching) need not
        # wait for the sender's answer. The order does not matter for the cut: the
        # sender raises it to what it evaluated before it held (docs/protocol.md).
        with ThreadPoolExecutor(max_workers=1) as pool:
            receiving = pool.submit(step, destination, "receive")
            try:
                step(source, "hold", peer=destination.base)
                mark("hold")
            except NOT_SENT:
                reached = False  # a setting to fix: the source holds nothing of this move
                raise
            finally:
                receiving.result()  # re-raises its error after the hold's
            mark("receive")
        while True:
            answer = _cut_answer(destination, step(destination, "cut")[1], names)
            waiting = sorted(n for n, c in answer["cuts"].items() if c is None)
            if not waiting:
                break
            if time.monotonic() > deadline:
                raise MigrationFailed(
                    f"{destination.base} could not take the cut of {', '.join(waiting)} "
                    f"within {timeout:g} s: on some topic it neither received a message nor "
                    "was matched with every publisher (docs/protocol.md, 'Silent topics')"
                )
            time.sleep(0.005)
        mark("cut")
        cuts = {n: c for n, c in answer["cuts"].items() if c is not None}  # all of them
        while True:
            # the sender waits for events past the cut itself (a round trip saved a try)
            wait = max(0.0, min(grace + 0.5, deadline - time.monotonic()))
            release = functools.partial(
                step, source, "release", cuts=cuts, quiet=answer["quiet"], grace=grace, wait=wait
            )
            status, bundle = _retry(deadline, release)
            if status == 200:
                break
            mark("release (waiting for events past the cut)")
            if time.monotonic() > deadline:
                raise MigrationFailed("the sender did not release the monitors in time")
            time.sleep(0.005)
        mark("release")
        try:  # checked before the receiver sees it: a bad one is undone like any failure
            sizes = [frame_sizes(frame) for frame in unbundle(bundle)]
        except (HandoffError, ValueError, KeyError, TypeError) as exc:
            raise MigrationFailed(f"{source.base} released no valid snapshots: {exc}") from None
        if len(sizes) != len(names):
            raise MigrationFailed(
                f"{source.base} released {len(sizes)} snapshots for {len(names)} monitors"
            )
    except ApiError as failed:
        until = time.monotonic() + timeout
        return _undo(source, destination, epoch, names, failed, until, reached)
    if after_release is not None:
        after_release()
    # The source has let go and keeps what it needs to resume: the adoption decides.
    try:
        _retry(
            deadline,
            lambda: destination.call(
                f"/v1/handoff/adopt?epoch={epoch}", raw=bundle, check=True, timeout=per_call
            ),
        )
    except ApiError as failed:
        until = time.monotonic() + timeout
        where, answers = _decide(source, destination, epoch, names, until)
        back = sorted(n for n in names if where[n] != destination.base)
        if back:
            state = ", ".join(f"{n} {answers[n]}" for n in back)
            resumed = " the sender resumed those" if source.base in where.values() else ""
            raise NotMoved(
                f"{_say(where, source, destination)}: {failed}; the destination had "
                f"{state}:{resumed}",
                where,
            ) from None
    seconds = time.monotonic() - started
    mark("adopt")
    note = _commit(source, epoch, names, deadline + timeout)
    mark("commit")
    headers, letters = sum(h for h, _ in sizes), sum(n for _, n in sizes)
    return Moved(seconds, len(bundle), letters, headers, steps, note=note)


def _commit(source: HandlerClient, epoch: int, names: Sequence[str], until: float) -> str:
    """Tell the source to let go of what the destination adopted; what is left to do
    when it did not confirm it ("" when it did, or is down: a crashed one let go too)."""
    try:
        _retry(until, lambda: source.handoff("commit", epoch, names, _left(until)))
    except (Refused, HttpError):
        return ""  # down, or it no longer has that handoff (restarted): nothing kept
    except ApiError as exc:
        return (
            f"{source.base} did not confirm it let go of {', '.join(names)} ({exc}): it "
            "keeps their snapshots, evaluated nowhere, until the same command is run "
            "again (or edgerv orchestrate's next round)"
        )
    return ""


def _abort(side: HandlerClient, epoch: int, names: Sequence[str], until: float) -> dict[str, str]:
    """``abort`` on one side, retried until ``until`` while it does not answer: its
    answer per monitor (Engine.handoffs.abort), UNDEFINED for one it does not define, or
    UNAUTHORIZED for each when it refuses the token.

    Raises MigrationFailed when it gave no usable answer (Refused: it is down)."""
    try:
        raw = _retry(until, lambda: side.handoff("abort", epoch, names, _left(until)))[1]
    except HttpError as exc:
        if exc.status in (401, 403):  # our token is refused: so was every call of ours
            return dict.fromkeys(names, UNAUTHORIZED)
        if exc.status != 409:
            raise
        if len(names) == 1:  # the only monitor it refuses to abort: one it does not define
            return {names[0]: UNDEFINED}
        answers: dict[str, str] = {}
        for name in names:  # a batch stops at the one it does not define: one by one
            answers.update(_abort(side, epoch, [name], until))
        return answers
    answer = side.json("the abort", raw)
    outcomes = answer.get("outcomes") if isinstance(answer, dict) else None
    if not isinstance(outcomes, dict) or not all(isinstance(outcomes.get(n), str) for n in names):
        raise MigrationFailed(f"{side.base} answered the abort with {raw[:200]!r}")
    return {n: str(outcomes[n]) for n in names}


def _resume(
    source: HandlerClient, epoch: int, names: Sequence[str], until: float, why: str, meanwhile: str
) -> dict[str, str]:
    """The source's ``abort`` of ``names`` (it resumes them), retried until ``until``: its
    answers (DOWN for each when it is down, holding nothing). Raises Unsettled when it
    does not answer: ``why`` the abort, and ``meanwhile`` how it may hold them."""
    try:
        return _abort(source, epoch, names, until)
    except Refused:
        return dict.fromkeys(names, DOWN)
    except ApiError as exc:
        raise Unsettled(
            f"{why}, and {source.base} did not confirm it resumed {', '.join(names)} ({exc}): "
            f"{meanwhile}",
            names,
            [source.base],
        ) from None


def _undo(
    source: HandlerClient,
    destination: HandlerClient,
    epoch: int,
    names: list[str],
    failed: ApiError,
    until: float,
    reached: bool = True,
) -> Moved:
    """A move failed before the adoption was sent: nothing of it can run on the
    destination, so the source may resume. Both sides are told to abort, the source
    until it answers or ``until`` (not when the hold never reached it: ``reached``
    False); then say where each monitor runs.

    Returns (all already ran on the destination) or raises NotMoved; raises Held when
    the source holds some for an earlier handoff (its hold was refused for that), and
    Unsettled while it does not answer: it may hold them, evaluated nowhere."""
    with ThreadPoolExecutor(max_workers=1) as pool:
        dropping = pool.submit(_abort, destination, epoch, names, until)
        try:
            answers = (
                _resume(
                    source,
                    epoch,
                    names,
                    until,
                    f"the move failed ({failed})",
                    "it may hold them for this move, evaluated nowhere (if it had not released "
                    f"them, they resume there by themselves within {HANDOFF_EXPIRES:.0f} s)",
                )
                if reached
                else {}
            )
        finally:
            dropped = dropping.exception()  # (a receiver that is down holds nothing)
    # (one that is down, or was never reached, holds nothing)
    lingering = dropped is not None and not isinstance(dropped, (Refused, *NOT_SENT))
    where: dict[str, str | None] = {}
    for n in names:
        answer = answers.get(n)
        where[n] = source.base if answer in RUNS else "" if answer in (DOWN, "gone") else None
    # 'nothing to undo' (this move never held it there) or not defined: the listings say
    look = [n for n, w in where.items() if w is None]
    states: dict[str, tuple[str, str]] = {}
    if look:
        mine, theirs = _entries(source, look, until), _entries(destination, look, until)
        held = [n for n in look if _state(mine, n) in ("sending", "released")]
        if held:
            raise Held(
                "; ".join(f"{n} {_whereabouts(mine, n)} on {source.base}" for n in held),
                held,
            )
        for n in look:
            if _state(mine, n) == "runs":
                where[n] = source.base
            elif _state(theirs, n) == "runs":
                where[n] = destination.base
            elif mine is not None and theirs is not None:
                where[n] = ""
                states[n] = (_whereabouts(mine, n), _whereabouts(theirs, n))
    if all(w == destination.base for w in where.values()):
        return Moved(0.0, 0, 0, 0, {}, already=names)
    said = _say(where, source, destination)
    for n, (here, there) in states.items():
        said += f" ({n}: {here} on {source.base}, {there} on {destination.base})"
    said += f": {failed}"
    if lingering:
        said += (
            f"; {destination.base} did not confirm it let go of what it received for this "
            f"move: until it does (within {HANDOFF_EXPIRES:.0f} s) it refuses to receive them"
        )
    raise NotMoved(said, where)


def _entries(side: HandlerClient, names: Sequence[str], until: float) -> dict[str, Any] | None:
    """Those of ``names`` a handler lists, by name (None when it does not answer)."""
    try:
        listing = _retry(until, lambda: side.monitors(timeout=_left(until)))
    except ApiError:
        return None
    return {m["name"]: m for m in listing if m["name"] in names}


def _state(entries: Mapping[str, Any] | None, name: str) -> str | None:
    """A monitor's state in a listing: its handoff state, ``runs`` (evaluated there),
    ``idle`` (defined, not run there), ``undefined``; None without a listing."""
    if entries is None:
        return None
    entry = entries.get(name)
    if entry is None:
        return "undefined"
    if entry.get("handoff"):
        return str(entry["handoff"])
    return "runs" if entry.get("active") else "idle"


def _whereabouts(entries: Mapping[str, Any] | None, name: str) -> str:
    """A monitor's state in a listing, in words."""
    state = _state(entries, name)
    entry = (entries or {}).get(name) or {}
    handoff = f"(epoch {entry.get('epoch')}, to {entry.get('peer') or 'another handler'})"
    return {
        None: "unknown (no listing)",
        "runs": "runs",
        "idle": "is defined but not run",
        "undefined": "is not defined",
        "sending": f"is held for a handoff {handoff}, not evaluated",
        "released": f"is held released in a handoff not yet settled {handoff}, not evaluated",
        "receiving": f"is being received in another handoff (epoch {entry.get('epoch')})",
    }.get(state, f"is in state {state}")


def _say(where: Mapping[str, str | None], source: HandlerClient, destination: HandlerClient) -> str:
    """Where each monitor runs, a clause a place: "m, p stay on S; q runs on D"."""
    groups: dict[str | None, list[str]] = {}
    for name, place in where.items():
        groups.setdefault(place, []).append(name)
    clauses = []
    for place, group in groups.items():
        who, one = ", ".join(group), len(group) == 1
        if place == source.base:
            clauses.append(f"{who} {'stays' if one else 'stay'} on {place}")
        elif place is None:
            clauses.append(f"{who}: nothing of this move took effect on {source.base}")
        elif place == "":
            clauses.append(
                f"{who} {'runs' if one else 'run'} on neither {source.base} nor {destination.base}"
            )
        else:
            clauses.append(f"{who} {'runs' if one else 'run'} on {place}")
    return "; ".join(clauses)


def _decide(
    source: HandlerClient, receiver: HandlerClient, epoch: int, names: Sequence[str], until: float
) -> tuple[dict[str, str], dict[str, str]]:
    """After a release: ask the receiver to abort, which answers per monitor whether it
    adopted it (``active``, or ``adopted`` when it moved it on since) or now never will;
    commit the adopted ones on the source and resume the others there, each call
    retried until ``until``. Returns where each monitor runs (the receiver's address,
    the source's, or "" for neither: moved on since, or the source down) and the
    receiver's answers (``down`` for each when it is down).

    Raises Unsettled while the receiver does not answer, or cannot say for some monitor
    (it may have adopted them, so the source goes on holding them: at most one active
    copy, tested), or while the source does not confirm it resumed those it did not.
    """

    try:
        answers = _abort(receiver, epoch, names, until)
    except Refused:
        answers = dict.fromkeys(names, DOWN)  # nothing listens there: it runs none of them
    except ApiError as exc:  # no answer, or an error: whether it adopted is unknown
        raise Unsettled(
            f"{receiver.base} did not say whether it adopted {', '.join(names)} ({exc}): "
            f"{source.base} holds {', '.join(names)} released, evaluated nowhere, and they "
            f"may run on {receiver.base}",
            names,
            [receiver.base],
        ) from None
    where = {n: receiver.base if answers[n] == "active" else "" for n in names}
    adopted = [n for n in names if answers[n] in ADOPTED]
    back = [n for n in names if answers[n] in (*NOT_ADOPTED, DOWN, UNDEFINED, UNAUTHORIZED)]
    if adopted:
        _commit(source, epoch, adopted, until)  # if unconfirmed: held, and settled again
    if back:
        did_not = f"{receiver.base} did not adopt {', '.join(back)}"
        resumed = _resume(
            source, epoch, back, until, did_not, "it holds them released, evaluated nowhere"
        )
        where.update({n: source.base for n in back if resumed[n] in RUNS})
        odd = [n for n in back if resumed[n] not in (*RUNS, DOWN)]  # it lost that handoff
        if odd:  # (restarted since?): whether it runs them is in its listing
            entries = _entries(source, odd, until)
            where.update({n: source.base for n in odd if _state(entries, n) == "runs"})
    unknown = [n for n in names if n not in adopted and n not in back]
    if unknown:
        raise Unsettled(
            f"{receiver.base} could not say whether it adopted {', '.join(unknown)} "
            f"({', '.join(sorted({answers[n] for n in unknown}))}): {source.base} keeps "
            "holding them, evaluated nowhere (they may run on the receiver) until that is "
            "known; settle by hand once you know where they run",
            unknown,
        )
    return where, answers


def _left(deadline: float) -> float:
    """A call's timeout: what is left until the deadline, within 0.5 to 10 seconds."""
    return max(0.5, min(10.0, deadline - time.monotonic()))


def settle(source: HandlerClient, names: Sequence[str], deadline: float) -> dict[str, list[str]]:
    """Settle the handoffs ``source`` still holds some of ``names`` for (its driver died or
    the receiver did not answer): those that sent nothing yet resume on the source (and
    the receiver lets go); of those released, the receiver it recorded says which it
    adopted: those commit, the others resume. Each call is retried until ``deadline``.
    Returns receiver -> monitors it runs now (the key "RECEIVER, which moved them on
    since" for those it adopted and moved on). Raises Unsettled while a handler does not
    answer: the source may go on holding them.
    """
    try:
        listing = _retry(deadline, lambda: source.monitors(timeout=_left(deadline)))
    except ApiError as exc:
        raise Unsettled(
            f"{source.base} did not list its monitors ({exc}): it may hold "
            f"{', '.join(names)} for a handoff, evaluated nowhere",
            names,
            [source.base],
        ) from None
    groups: dict[tuple[int, str | None, str], list[str]] = {}
    for m in listing:
        if m["name"] in names and m.get("handoff") in ("sending", "released"):
            epoch, peer = m.get("epoch"), m.get("peer")
            if not isinstance(epoch, int) or not (peer is None or isinstance(peer, str)):
                raise Unsettled(f"{source.base} lists {m['name']} without its handoff")
            key = (epoch, peer, str(m["handoff"]))
            groups.setdefault(key, []).append(str(m["name"]))
    moved: dict[str, list[str]] = {}
    for (epoch, peer, state), group in groups.items():
        receiver = HandlerClient(peer, source.token, source.tls) if peer else None
        if state == "sending":  # nothing left the source: it resumes; the receiver drops
            if receiver is not None:
                with contextlib.suppress(ApiError):
                    receiver.handoff("abort", epoch, group, _left(deadline), check=False)
            _resume(
                source,
                epoch,
                group,
                deadline,
                f"{source.base} holds them for a handoff (epoch {epoch}) that sent nothing",
                f"evaluated nowhere until it does (by itself within {HANDOFF_EXPIRES:.0f} s)",
            )
            continue
        if receiver is None:
            raise Unsettled(
                f"{', '.join(group)} were released by {source.base} to a receiver it does "
                "not know: abort the handoff there once you know the receiver does not run them",
                group,
            )
        _, answers = _decide(source, receiver, epoch, group, deadline)
        adopted = [n for n in group if answers.get(n) == "active"]
        if adopted:
            moved.setdefault(receiver.base, []).extend(adopted)
        on = [n for n in group if answers.get(n) == "adopted"]  # adopted, moved on since
        if on:
            moved.setdefault(f"{receiver.base}, which moved them on since", []).extend(on)
    return moved
