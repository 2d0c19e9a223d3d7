"""``edgerv migrate``: move one monitor from a handler to another, by their HTTP APIs.

The steps of docs/protocol.md, driven from outside: the receiver subscribes and
holds, the sender holds, the receiver reports the cut, the sender releases the
snapshot, the receiver adopts it. Any failure before the adoption aborts both
sides: the monitor resumes on the sender with nothing lost. Exit 0 once the
monitor runs on the receiver, 1 with the reason otherwise, 2 on bad arguments.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import sys
import time
import urllib.error
import urllib.request
from typing import Any


class MigrationFailed(Exception):
    pass


class Handler:
    def __init__(self, address: str, token: str | None) -> None:
        self.base = address if "://" in address else f"http://{address}"
        self.token = token

    def call(
        self, path: str, body: Any = None, raw: bytes | None = None, timeout: float = 10.0
    ) -> tuple[int, bytes]:
        data = raw if raw is not None else json.dumps(body or {}).encode()
        headers = {
            "Content-Type": "application/octet-stream" if raw is not None else "application/json"
        }
        if self.token:
            headers["Authorization"] = f"Bearer {self.token}"
        req = urllib.request.Request(self.base + path, data=data, method="POST", headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=timeout) as resp:
                return resp.status, resp.read()
        except urllib.error.HTTPError as err:
            return err.code, err.read()
        except OSError as exc:
            raise MigrationFailed(f"{self.base} is unreachable: {exc}") from None

    def step(
        self, monitor: str, step: str, body: Any = None, raw: bytes | None = None, query: str = ""
    ) -> tuple[int, bytes]:
        status, data = self.call(f"/v1/monitors/{monitor}/handoff/{step}{query}", body, raw)
        if status >= 400:
            try:
                reason = json.loads(data)["errors"][0]["message"]
            except (ValueError, KeyError, IndexError):
                reason = data[:200].decode(errors="replace")
            raise MigrationFailed(f"{self.base}: {step}: {reason} (HTTP {status})")
        return status, data


def migrate(
    source: Handler, destination: Handler, monitor: str, timeout: float, grace: float
) -> float:
    """Move ``monitor``; return the seconds it took. Raises MigrationFailed after undoing."""
    epoch = time.time_ns()
    started = time.monotonic()
    deadline = started + timeout
    try:
        source.step(monitor, "hold", {"epoch": epoch})  # 2a first, as in the paper
        destination.step(monitor, "receive", {"epoch": epoch})
        cut = None
        while cut is None:
            cut = json.loads(destination.step(monitor, "cut", {"epoch": epoch})[1])["cut"]
            if cut is None:
                if time.monotonic() > deadline:
                    raise MigrationFailed(
                        f"{destination.base} received no message on some "
                        f"topic of '{monitor}' within {timeout:g} s"
                    )
                time.sleep(0.01)
        while True:
            status, snapshot = source.step(
                monitor, "release", {"epoch": epoch, "cut": cut, "grace": grace}
            )
            if status == 200:
                break
            if time.monotonic() > deadline:
                raise MigrationFailed("the sender did not release the monitor in time")
            time.sleep(0.01)
    except MigrationFailed:
        for side in (source, destination):
            with contextlib.suppress(MigrationFailed):  # best effort: report the first error
                side.step(monitor, "abort", {"epoch": epoch})
        raise
    # From here the sender has let go: the receiver must adopt (retrying is safe: fenced).
    for attempt in range(5):
        try:
            destination.step(monitor, "adopt", raw=snapshot, query=f"?epoch={epoch}")
            return time.monotonic() - started
        except MigrationFailed:
            if attempt == 4:
                raise
            time.sleep(0.2)
    raise AssertionError("unreachable")


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
    p.add_argument("--monitor", required=True, help="the monitor's name")
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
    try:
        seconds = migrate(
            Handler(args.source, token),
            Handler(args.destination, token),
            args.monitor,
            args.timeout,
            args.grace,
        )
    except MigrationFailed as exc:
        print(f"edgerv migrate: {args.monitor} stays on {args.source}: {exc}", file=sys.stderr)
        return 1
    print(
        f"edgerv migrate: {args.monitor} runs on {args.destination} ({seconds * 1000:.0f} ms)",
        file=sys.stderr,
    )
    return 0
