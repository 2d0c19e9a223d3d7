"""``edgerv migrate``: move one monitor from a handler to another, by their HTTP APIs.

The steps of docs/protocol.md, driven from outside: the receiver subscribes and
holds, the sender holds, the receiver reports the cut, the sender releases the
snapshot, the receiver adopts it. Any failure before the adoption aborts both
sides: the monitor resumes on the sender with nothing lost. Exit 0 once the
monitor runs on the receiver, 1 with the reason otherwise (it runs on the
sender), 2 on bad arguments, 3 when the receiver did not say whether it adopted
it: the sender holds it, active nowhere, until the same command is run again.
"""

from __future__ import annotations

import argparse
import contextlib
import functools
import http.client
import json
import os
import sys
import time
import urllib.parse
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Any, TypeVar

from edgerv.core.handoff import HandoffError, frame_sizes, unbundle


class MigrationFailed(Exception):
    pass


class Unreachable(MigrationFailed):
    """The handler did not answer (refused, reset, timed out)."""


class Rejected(MigrationFailed):
    """The handler answered with an HTTP error."""

    def __init__(self, message: str, status: int) -> None:
        super().__init__(message)
        self.status = status


class Refused(Unreachable):
    """Nothing listens at the handler's address: it is down, and runs no monitor."""


class Unsettled(MigrationFailed):
    """After the release, the destination did not say whether it adopted: the source
    holds the monitors (active nowhere) until it does. Running the same migration
    again settles them (:func:`settle`)."""


T = TypeVar("T")

# A receiver's answers to ``abort`` after a release (Engine.abort): it adopted the monitor
# (runs it now, or moved it on since), or it never will; any other leaves it held.
ADOPTED = ("active", "adopted")
NOT_ADOPTED = ("dropped", "nothing to undo", "gone")


class Handler:
    """A handler's control API, over one kept-alive connection (a round trip per call)."""

    def __init__(self, address: str, token: str | None) -> None:
        self.base = address if "://" in address else f"http://{address}"
        self.token = token
        parts = urllib.parse.urlsplit(self.base)
        self._https = parts.scheme == "https"
        self._netloc = parts.netloc
        self._conn: http.client.HTTPConnection | None = None

    def _connection(self, timeout: float) -> http.client.HTTPConnection:
        if self._conn is None:
            cls = http.client.HTTPSConnection if self._https else http.client.HTTPConnection
            self._conn = cls(self._netloc, timeout=timeout)
        self._conn.timeout = timeout
        if self._conn.sock is not None:
            self._conn.sock.settimeout(timeout)
        return self._conn

    def close(self) -> None:
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def call(
        self,
        path: str,
        body: Any = None,
        raw: bytes | None = None,
        timeout: float = 10.0,
        check: bool = False,
        method: str = "POST",
    ) -> tuple[int, bytes]:
        """One request; with ``check``, a 4xx/5xx answer raises MigrationFailed with its reason.

        Every call of the protocol is idempotent, so a call on a kept-alive connection
        that the handler had closed is sent once more on a new one.
        """
        data = raw if raw is not None else json.dumps(body or {}).encode()
        headers = {
            "Content-Type": "application/octet-stream" if raw is not None else "application/json"
        }
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        for attempt in (1, 2):
            reused = self._conn is not None and self._conn.sock is not None
            conn = self._connection(timeout)
            try:
                conn.request(
                    method, path, body=data if method in ("POST", "PUT") else None, headers=headers
                )
                resp = conn.getresponse()
                status, answer = resp.status, resp.read()
                break
            except (http.client.HTTPException, OSError) as exc:
                self.close()
                if attempt == 1 and reused and not isinstance(exc, TimeoutError):
                    continue  # the kept-alive connection had been closed: once more
                kind = Refused if isinstance(exc, ConnectionRefusedError) else Unreachable
                raise kind(f"{self.base} is unreachable: {exc}") from None
        if check and status >= 400:
            try:
                reason = json.loads(answer)["errors"][0]["message"]
            except (ValueError, KeyError, IndexError, TypeError):
                reason = answer[:200].decode(errors="replace")
            raise Rejected(f"{self.base}{path}: {reason} (HTTP {status})", status)
        return status, answer

    def handoff(
        self,
        step: str,
        epoch: int,
        monitors: Sequence[str],
        timeout: float,
        check: bool = True,
        **body: Any,
    ) -> tuple[int, bytes]:
        """One step of a handoff (docs/protocol.md) for ``monitors`` under ``epoch``."""
        return self.call(
            f"/v1/handoff/{step}",
            {"epoch": epoch, "monitors": list(monitors), **body},
            check=check,
            timeout=timeout,
        )

    def get(self, path: str, timeout: float = 10.0) -> Any:
        """GET a JSON document (raises MigrationFailed on errors)."""
        return _json(self, path, self.call(path, timeout=timeout, check=True, method="GET")[1])


def _json(side: Handler, what: str, raw: bytes) -> Any:
    """A peer's answer as JSON, or MigrationFailed naming the peer and the step."""
    try:
        return json.loads(raw)
    except (ValueError, RecursionError):
        raise MigrationFailed(f"{side.base} answered {what} with something not JSON") from None


def _cut_answer(side: Handler, raw: bytes, names: Sequence[str]) -> tuple[dict[str, Any], Any]:
    """The cut step's answer, checked: a cut (integer nanoseconds, or null: not yet) for
    every monitor asked about, and the topics it vouched for (lists of names)."""
    answer = _json(side, "the cut", raw)
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
    return cuts, quiet


def _listing(side: Handler, timeout: float) -> list[dict[str, Any]]:
    """GET /v1/monitors, checked: a list of monitors, each with its name."""
    listing = side.get("/v1/monitors", timeout=timeout)
    monitors = listing.get("monitors") if isinstance(listing, dict) else None
    if not isinstance(monitors, list) or not all(
        isinstance(m, dict) and isinstance(m.get("name"), str) for m in monitors
    ):
        raise MigrationFailed(f"{side.base} answered /v1/monitors with no list of monitors")
    return monitors


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


def migrate(
    source: Handler,
    destination: Handler,
    monitors: Sequence[str],
    timeout: float = 30.0,
    grace: float = 1.0,
    after_release: Callable[[], None] | None = None,
) -> Moved:
    """Move ``monitors`` (one handoff, one epoch). Raises MigrationFailed after undoing.

    Up to the release, any failure aborts both sides: the monitors resume on the
    source. After it, the destination's adoption decides who owns each monitor
    (docs/protocol.md, "Failures"): adopted -> the source commits (lets go); not
    adopted, or the destination down (its port refuses) -> the destination is
    fenced and the source resumes from the snapshot and the events it kept; no
    answer -> Unsettled: the source keeps holding them. Monitors the source still
    holds from such an interrupted handoff are settled first, then moved.
    (``after_release`` is a seam for tests that break things at that moment.)
    """
    started = time.monotonic()
    try:
        return _migrate(source, destination, list(monitors), timeout, grace, after_release)
    except Held as held:
        # Some of them are still held from an interrupted handoff: settle that one, then
        # move what came back to the source.
        moved = settle(source, held.names, started + timeout)
        here = moved.get(destination.base, [])
        elsewhere = {p: n for p, n in moved.items() if p != destination.base}
        if elsewhere:
            where = "; ".join(f"{', '.join(n)} on {p}" for p, n in elsewhere.items())
            raise MigrationFailed(f"an earlier handoff had moved them: {where}") from None
        rest = [n for n in monitors if n not in here]
        if not rest:
            seconds = time.monotonic() - started
            return Moved(seconds, 0, 0, 0, {"settle": seconds})
        return _migrate(source, destination, rest, timeout, grace, after_release)


class Held(MigrationFailed):
    """The source holds some of the monitors for an earlier, interrupted handoff."""

    def __init__(self, message: str, names: list[str]) -> None:
        super().__init__(message)
        self.names = names


def _migrate(
    source: Handler,
    destination: Handler,
    names: list[str],
    timeout: float,
    grace: float,
    after_release: Callable[[], None] | None,
) -> Moved:
    epoch = time.time_ns()
    started = time.monotonic()
    deadline = started + timeout
    per_call = min(10.0, timeout)

    def step(side: Handler, name: str, **body: Any) -> tuple[int, bytes]:
        timeout = per_call + float(body.get("wait", 0.0))
        return side.handoff(name, epoch, body.pop("monitors", names), timeout, **body)

    steps: dict[str, float] = {}

    def mark(name: str) -> None:
        steps[name] = time.monotonic() - started

    try:
        # 2a and 2b at once: the receiver's subscription (and its DDS matching) need not
        # wait for the sender's answer. The order does not matter for the cut: the
        # sender raises it to what it evaluated before it held (docs/protocol.md).
        with ThreadPoolExecutor(max_workers=1) as pool:
            receiving = pool.submit(step, destination, "receive")
            try:
                step(source, "hold", peer=destination.base)
                mark("hold")
            finally:
                receiving.result()  # re-raises its error after the hold's
            mark("receive")
        while True:
            cuts, quiet = _cut_answer(destination, step(destination, "cut")[1], names)
            waiting = sorted(n for n, c in cuts.items() if c is None)
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
        while True:
            # the sender waits for events past the cut itself (a round trip saved a try)
            wait = max(0.0, min(grace + 0.5, deadline - time.monotonic()))
            release = functools.partial(
                step, source, "release", cuts=cuts, quiet=quiet, grace=grace, wait=wait
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
    except MigrationFailed as failed:
        for side in (source, destination):
            with contextlib.suppress(MigrationFailed):  # best effort: report the first error
                step(side, "abort")
        if "hold" not in steps:
            held = _held(source, names)
            if held:
                raise Held(str(failed), held) from None
        raise
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
    except MigrationFailed as failed:
        _settle(epoch, names, source, destination, deadline + timeout, failed)
    seconds = time.monotonic() - started
    mark("adopt")
    with contextlib.suppress(MigrationFailed):  # a source that crashed has let go too
        _retry(deadline + timeout, lambda: step(source, "commit"))
    mark("commit")
    headers, letters = sum(h for h, _ in sizes), sum(n for _, n in sizes)
    return Moved(seconds, len(bundle), letters, headers, steps)


def _decide(
    source: Handler, receiver: Handler, epoch: int, names: Sequence[str], deadline: float
) -> dict[str, str]:
    """After a release: ask the receiver to abort, which answers per monitor whether it
    adopted it (``active``, or ``adopted`` when it moved it on since) or now never will;
    commit the adopted ones on the source and resume the others there. Returns the
    receiver's answers (``down`` for each when it is down).

    Raises Unsettled while the receiver does not answer, or cannot say for some monitor:
    it may have adopted them, so the source goes on holding them (at most one active
    copy, tested).
    """

    try:
        raw = _retry(deadline, lambda: receiver.handoff("abort", epoch, names, _left(deadline)))[1]
        outcomes = _json(receiver, "the abort", raw)
        answers = outcomes.get("outcomes") if isinstance(outcomes, dict) else None
        if not isinstance(answers, dict):
            raise MigrationFailed(f"{receiver.base} answered the abort with {raw[:200]!r}")
    except Refused:
        answers = dict.fromkeys(names, "down")  # nothing listens there: it runs none of them
    except MigrationFailed as exc:  # no answer, or an error: whether it adopted is unknown
        raise Unsettled(
            f"{receiver.base} did not say whether it adopted them ({exc}): "
            f"{', '.join(names)} stay held on {source.base}, active nowhere, until it "
            "does; run the same migration again to settle them"
        ) from None
    adopted = [n for n in names if answers.get(n) in ADOPTED]
    back = [n for n in names if answers.get(n) in (*NOT_ADOPTED, "down")]
    if adopted:
        with contextlib.suppress(MigrationFailed):  # a source that crashed has let go too
            _retry(deadline, lambda: source.handoff("commit", epoch, adopted, _left(deadline)))
    if back:
        try:
            _retry(deadline, lambda: source.handoff("abort", epoch, back, _left(deadline)))
        except MigrationFailed as exc:
            raise Unsettled(
                f"the sender could not resume {', '.join(back)}: {exc} (it keeps their "
                "snapshots: run the same migration again once it is reachable)"
            ) from None
    unknown = [n for n in names if n not in adopted and n not in back]
    if unknown:
        raise Unsettled(
            f"{receiver.base} could not say whether it adopted {', '.join(unknown)} "
            f"({', '.join(sorted({str(answers.get(n)) for n in unknown}))}): {source.base} "
            "keeps holding them (they may run there) until that is known"
        )
    return answers


def _settle(
    epoch: int,
    names: Sequence[str],
    source: Handler,
    destination: Handler,
    deadline: float,
    failed: MigrationFailed,
) -> None:
    """The adoption failed or its answer was lost: find out, then commit or resume.

    Returns when the destination runs them all; raises MigrationFailed when some
    resumed on the source, Unsettled while the destination does not answer.
    """
    answers = _decide(source, destination, epoch, names, deadline)
    back = [n for n in names if answers.get(n) not in ADOPTED]
    if back:
        state = ", ".join(f"{n} {answers[n]}" for n in sorted(back))
        raise MigrationFailed(f"{failed}; the destination had {state}: the sender resumed those")


def _left(deadline: float) -> float:
    """A call's timeout: what is left until the deadline, within 0.5 to 10 seconds."""
    return max(0.5, min(10.0, deadline - time.monotonic()))


def _held(source: Handler, names: Sequence[str]) -> list[str]:
    """Those of ``names`` the source holds for a handoff (none if it does not answer)."""
    try:
        listing = _listing(source, 5.0)
    except MigrationFailed:
        return []
    return [m["name"] for m in listing if m["name"] in names and m.get("handoff")]


def settle(source: Handler, names: Sequence[str], deadline: float) -> dict[str, list[str]]:
    """Settle the handoffs ``source`` still holds some of ``names`` for (its driver died or
    the receiver did not answer): those that sent nothing yet resume on the source (and
    the receiver lets go); of those released, the receiver it recorded says which it
    adopted: those commit, the others resume. Returns receiver -> monitors it runs now.
    Raises Unsettled while such a receiver does not answer.
    """
    listing = _listing(source, _left(deadline))
    groups: dict[tuple[int, str | None, str], list[str]] = {}
    for m in listing:
        if m["name"] in names and m.get("handoff") in ("sending", "released"):
            epoch, peer = m.get("epoch"), m.get("peer")
            if not isinstance(epoch, int) or not (peer is None or isinstance(peer, str)):
                raise MigrationFailed(f"{source.base} lists {m['name']} without its handoff")
            key = (epoch, peer, str(m["handoff"]))
            groups.setdefault(key, []).append(str(m["name"]))
    moved: dict[str, list[str]] = {}
    for (epoch, peer, state), group in groups.items():
        receiver = Handler(peer, source.token) if peer else None
        if state == "sending":  # nothing left the source: it resumes; the receiver drops
            if receiver is not None:
                with contextlib.suppress(MigrationFailed):
                    receiver.handoff("abort", epoch, group, _left(deadline), check=False)
            source.handoff("abort", epoch, group, _left(deadline))
            continue
        if receiver is None:
            raise Unsettled(
                f"{', '.join(group)} were released by {source.base} to a receiver it does "
                "not know: abort the handoff there once you know the receiver does not run them"
            )
        answers = _decide(source, receiver, epoch, group, deadline)
        adopted = [n for n in group if answers.get(n) == "active"]
        if adopted:
            moved.setdefault(receiver.base, []).extend(adopted)
        on = [n for n in group if answers.get(n) == "adopted"]  # adopted, moved on since
        if on:
            moved.setdefault(f"{receiver.base}, which moved them on since", []).extend(on)
    return moved


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument(
        "--from",
        dest="source",
        required=True,
        metavar="HOST:PORT",
        help="the handler running the monitor now",
    )
    p.add_argument(
        "--to", dest="destination", required=True, metavar="HOST:PORT", help="the handler to run it"
    )
    p.add_argument(
        "--monitor",
        required=True,
        action="append",
        metavar="NAME[,NAME...]",
        help="the monitor(s) to move, in one handoff (repeat or separate with commas)",
    )
    p.add_argument("--timeout", type=float, default=30.0, metavar="SECONDS")
    p.add_argument(
        "--grace",
        type=float,
        default=1.0,
        metavar="SECONDS",
        help="how long the sender waits for an event past the cut (default 1)",
    )


def run(args: argparse.Namespace) -> int:
    token = os.environ.get("EDGERV_TOKEN")
    names = [n.strip() for item in args.monitor for n in item.split(",") if n.strip()]
    what = ", ".join(names)
    try:
        moved = migrate(
            Handler(args.source, token),
            Handler(args.destination, token),
            names,
            args.timeout,
            args.grace,
        )
    except Unsettled as exc:
        print(f"edgerv migrate: {what}: unsettled: {exc}", file=sys.stderr)
        return 3
    except MigrationFailed as exc:
        print(f"edgerv migrate: {what} stays on {args.source}: {exc}", file=sys.stderr)
        return 1
    print(
        f"edgerv migrate: {what} runs on {args.destination} ({moved.seconds * 1000:.0f} ms, "
        f"{moved.snapshot_bytes} bytes for {moved.letters} buffered events)",
        file=sys.stderr,
    )
    return 0
