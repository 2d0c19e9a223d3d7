"""``edgerv migrate``: move monitors from a handler to another, by their HTTP APIs:
the handoff of :mod:`edgerv.control.migrate`, its outcome as an exit code (0 moved, 1
not moved, 2 bad arguments, 3 unsettled: a handler did not answer in time).

The command first checks that each handler can be used as given (its scheme, its
certificate, its host's name: one ``GET /healthz`` each) and says what to change before
anything is held (exit 1); every "run again" line it prints is the command as given.
"""

from __future__ import annotations

import argparse
import contextlib
import math
import os
import shlex
import sys
import urllib.parse
from collections.abc import Callable, Mapping, Sequence

from edgerv.control.client import (
    ApiError,
    HandlerClient,
    Unresolved,
    Untrusted,
    WrongScheme,
    address_problem,
)
from edgerv.control.migrate import NotMoved, Unsettled, migrate
from edgerv.control.tls import ClientTls, is_loopback
from edgerv.core.diagnostics import Diagnostic, InputError, Location

DESCRIPTION = """\
Move monitors from one handler to another through their control APIs, with no
event lost or evaluated twice (the handoff of docs/protocol.md): the receiver
subscribes, the sender holds the monitors, the receiver reports the cut, the
sender releases their state and the receiver adopts it. A failure before the
adoption undoes the move: the monitors run on the sender again. After a failure
the calls are retried for up to --timeout seconds more; then it says where each
monitor runs as the handlers confirmed it, or that it could not confirm it.
Authenticates with the token in EDGERV_TOKEN, as the handlers do.
"""

EXIT_CODES = """\
exit codes:
  0  every monitor runs on --to (moved now, or it ran there already)
  1  not moved: the message says where each monitor runs (on --from again, or
     where an earlier handoff left it), as the handlers confirmed it; or, before
     anything was held, a handler could not be used as given (it speaks HTTPS
     and was given no --ca-file, or plain HTTP and was given one; its
     certificate is not trusted; its host name is not known): the message says
     what to change, and the monitors run where they ran
  2  bad arguments
  3  unsettled: a handler did not answer in time, so where some monitor runs is
     not confirmed (held by --from and evaluated nowhere, or running on --to);
     the message names the handler(s) that did not answer. Run the same command
     again once they answer (the message spells it out, every option kept): it
     finishes the move, or undoes it and moves them afresh.
"""


def add_client_arguments(p: argparse.ArgumentParser) -> None:
    """A caller's TLS options (``edgerv migrate``, ``edgerv orchestrate``)."""
    p.add_argument(
        "--ca-file",
        metavar="FILE",
        help="verify the handlers' certificates against this CA (PEM; default: the "
        "system's CAs). A HOST:PORT is reached over HTTPS, except a loopback one when "
        "neither this nor --tls-server-name is given; http://HOST:PORT asks for plain HTTP",
    )
    p.add_argument(
        "--tls-server-name",
        metavar="NAME",
        help="the name the handlers' certificates carry, when it is not the address "
        "(the chart's: RELEASE-handler.NAMESPACE.svc)",
    )


def client_tls(args: argparse.Namespace) -> ClientTls | None:
    """:class:`ClientTls` from :func:`add_client_arguments`'s options (None if neither)."""
    if args.ca_file is None and args.tls_server_name is None:
        return None
    return ClientTls(args.ca_file, args.tls_server_name)


TIMEOUT, GRACE = 30.0, 1.0  # the defaults of --timeout and --grace


class HelpFormatter(argparse.RawDescriptionHelpFormatter):
    """Help as written (the description and the exit codes keep their lines), each
    option's default after its help: ``(default: 30.0)``; none for an option without one."""

    def _get_help_string(self, action: argparse.Action) -> str | None:
        text = action.help or ""
        default = action.default
        if (
            "%(default)" in text
            or not action.option_strings
            or default is None
            or default is False
            or default == ""
            or default is argparse.SUPPRESS
        ):
            return text
        return f"{text} (default: %(default)s)" if text else "(default: %(default)s)"


def handler_address(text: str) -> str:
    """A handler's address as given (``HOST:PORT``, or ``http[s]://HOST[:PORT]``)."""
    problem = address_problem(text)
    if problem:
        form = "" if "HOST:PORT" in problem else " (HOST:PORT, or http[s]://HOST:PORT)"
        raise argparse.ArgumentTypeError(problem + form)
    return text


def finite(what: str, zero: bool) -> Callable[[str], float]:
    """An option's type: a finite number from 0 (``zero``) or above it, else the error
    ``'TEXT' is not WHAT``."""

    def number(text: str) -> float:
        with contextlib.suppress(ValueError):
            value = float(text)
            if (value >= 0 if zero else value > 0) and value < math.inf:
                return value
        raise argparse.ArgumentTypeError(f"'{text}' is not {what}")

    return number


seconds_above_zero = finite("a number of seconds above 0", zero=False)
seconds_from_zero = finite("a number of seconds from 0", zero=True)


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.epilog = EXIT_CODES
    p.formatter_class = HelpFormatter
    add_client_arguments(p)
    p.add_argument(
        "--from",
        dest="source",
        required=True,
        type=handler_address,
        metavar="HOST:PORT",
        help="the handler running the monitors now",
    )
    p.add_argument(
        "--to",
        dest="destination",
        required=True,
        type=handler_address,
        metavar="HOST:PORT",
        help="the handler to run them",
    )
    p.add_argument(
        "--monitor",
        required=True,
        action="append",
        metavar="NAME[,NAME...]",
        help="the monitor(s) to move, in one handoff (repeat or separate with commas)",
    )
    p.add_argument(
        "--timeout",
        type=seconds_above_zero,
        default=TIMEOUT,
        metavar="SECONDS",
        help="for the move; after a failure, as long again to settle it",
    )
    p.add_argument(
        "--grace",
        type=seconds_from_zero,
        default=GRACE,
        metavar="SECONDS",
        help="how long the sender waits for an event past the cut",
    )


def monitor_names(given: Sequence[str]) -> list[str]:
    """The monitors of the ``--monitor`` options, in order, each once."""
    names = [n.strip() for item in given for n in item.split(",") if n.strip()]
    if not names:
        raise InputError([Diagnostic(Location("--monitor"), "names no monitor")])
    return list(dict.fromkeys(names))


def _seconds(value: float) -> str:
    """A number of seconds as one would type it (30, 0.3), read back as the same float."""
    text = f"{value:g}"
    return text if float(text) == value else repr(value)


def command_line(args: argparse.Namespace, names: Sequence[str]) -> str:
    """This command as it was given (every option kept, each word quoted for a shell):
    the one to run again. (The token is not in it: the same EDGERV_TOKEN is read.)"""
    words = ["edgerv", "migrate", "--from", args.source, "--to", args.destination]
    words += ["--monitor", ",".join(names)]
    if args.timeout != TIMEOUT:
        words += ["--timeout", _seconds(args.timeout)]
    if args.grace != GRACE:
        words += ["--grace", _seconds(args.grace)]
    if args.ca_file is not None:
        words += ["--ca-file", args.ca_file]
    if args.tls_server_name is not None:
        words += ["--tls-server-name", args.tls_server_name]
    if getattr(args, "debug", False):
        words.append("--debug")
    return shlex.join(words)


def _unusable(
    sides: Mapping[str, tuple[str, HandlerClient]],
    args: argparse.Namespace,
    token: str | None,
    timeout: float,
) -> str:
    """Before anything is held: can each handler be reached as given (its scheme, its
    certificate, its host's name)? One ``GET /healthz`` each (it needs no token, and the
    connection is kept for the move). What to change, or "" when nothing: a handler that
    does not answer now is left to the move, which says what it finds."""
    https: list[str] = []  # the addresses of those that speak HTTPS, called over plain HTTP
    plain: list[str] = []  # and the reverse
    said: dict[str, str] = {}  # address -> how it was given ("--from ADDRESS")
    problems: list[str] = []
    for role, (address, side) in sides.items():
        said[address] = f"{role} {address}"
        try:
            side.call("/healthz", method="GET", timeout=timeout)
        except WrongScheme as exc:
            (https if exc.speaks == "https" else plain).append(address)
        except Untrusted as exc:
            problems.append(f"{role} {address}: {_untrusted_hint(exc, args)}")
        except Unresolved as exc:
            problems.append(f"{role} {address}: {exc.detail}")
        except ApiError:
            pass
    if plain:
        problems.insert(0, _plain_hint(plain, said, args))
    if https:
        one = len(https) == 1
        signed = "its certificate" if one else "their certificates"
        hint = f"give --ca-file (the CA that signed {signed})"
        if any(a.startswith("http://") for a in https):
            hint += f" and {'its address' if one else 'their addresses'} without http://"
        if not token:
            hint += ", and the token in EDGERV_TOKEN"
        who = " and ".join(said[a] for a in https)
        problems.insert(0, f"{who} {'speaks' if one else 'speak'} HTTPS: {hint}")
    return "; ".join(problems)


def _plain_hint(addresses: Sequence[str], said: Mapping[str, str], args: argparse.Namespace) -> str:
    """What to change for handlers that speak plain HTTP, called over HTTPS."""
    rests = [a.partition("://")[2] or a for a in addresses]
    urls = " and ".join(f"http://{r.rstrip('/')}" for r in rests)
    local = all(is_loopback(urllib.parse.urlsplit(f"//{r}").hostname or "") for r in rests)
    tls = [f for f, v in (("--ca-file", args.ca_file), ("--tls-server-name", args.tls_server_name))
           if v is not None]  # fmt: skip
    one = len(addresses) == 1
    who = " and ".join(said[a] for a in addresses)
    hint = f"use {urls}"
    if tls and local and not any("://" in a for a in addresses):
        hint = f"drop {' and '.join(tls)}, or use {urls}"
    if not local:
        hint += " (the token then crosses the network in clear)"
    return f"{who} {'speaks' if one else 'speak'} plain HTTP: {hint}"


def _untrusted_hint(exc: Untrusted, args: argparse.Namespace) -> str:
    """What to change for a handler whose certificate is not trusted."""
    said = f"its certificate is not trusted ({exc.reason})"
    if "hostname" in exc.reason.lower() or "ip address mismatch" in exc.reason.lower():
        return f"{said}: give --tls-server-name with the name it carries"
    if args.ca_file is None:
        return f"{said}: give --ca-file with the CA that signed it"
    return f"{said}: check that --ca-file is the CA that signed it, and that this is the handler"


def run(args: argparse.Namespace) -> int:
    token = os.environ.get("EDGERV_TOKEN")
    try:
        tls = client_tls(args)
        names = monitor_names(args.monitor)
        source = HandlerClient(args.source, token, tls)
        destination = HandlerClient(args.destination, token, tls)
        if source.base == destination.base:
            raise InputError(
                [Diagnostic(Location("--to"), f"{args.destination} is the handler of --from too")]
            )
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2
    what = ", ".join(names)
    sides = {"--from": (args.source, source), "--to": (args.destination, destination)}
    unusable = _unusable(sides, args, token, min(10.0, args.timeout))
    if unusable:
        where = "runs where it ran" if len(names) == 1 else "run where they ran"
        print(
            f"edgerv migrate: not moved: {unusable}; nothing was held: {what} {where}",
            file=sys.stderr,
        )
        return 1
    again = command_line(args, names)
    try:
        moved = migrate(source, destination, names, args.timeout, args.grace)
    except Unsettled as exc:
        silent = " and ".join(exc.silent) or "the handlers"
        print(
            f"edgerv migrate: {what}: unsettled: {exc}\n"
            f"edgerv migrate: run `{again}` again once {silent} "
            "answer(s): it finishes the move or undoes it",
            file=sys.stderr,
        )
        return 3
    except NotMoved as exc:
        print(f"edgerv migrate: not moved: {exc}", file=sys.stderr)
        return 1
    except ApiError as exc:  # (not expected: every failure above says where they run)
        print(
            f"edgerv migrate: {what}: unsettled: {exc}\n"
            f"edgerv migrate: run `{again}` again once the handlers answer: it finishes the "
            "move or undoes it",
            file=sys.stderr,
        )
        return 3
    fresh = [n for n in names if n not in moved.already]
    if fresh:
        print(
            f"edgerv migrate: {', '.join(fresh)} runs on {args.destination} "
            f"({moved.seconds * 1000:.0f} ms, {moved.snapshot_bytes} bytes for "
            f"{moved.letters} buffered events)",
            file=sys.stderr,
        )
    if moved.already:
        print(
            f"edgerv migrate: {', '.join(moved.already)} ran on {args.destination} already "
            "(nothing to move)",
            file=sys.stderr,
        )
    if moved.note:
        print(f"edgerv migrate: {moved.note}: `{again}`", file=sys.stderr)
    return 0
