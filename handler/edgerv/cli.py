"""The ``edgerv`` command line.

Exit codes: 0 no monitor violated, 1 a monitor was violated, 2 bad input (for
``check`` also: no message of any monitored topic read, or with ``--strict`` a
monitored topic without a message), 70 an internal error of edgerv's (any command: one
line says what failed, ``--debug`` adds the traceback; never 0 or 1, which a CI job
reads as verdicts). ``migrate`` adds 3 (unsettled).
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import os
import sys
import time
import traceback
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import NoReturn

from edgerv import __version__
from edgerv.core.checker import CheckRun, MonitorResult, check_types
from edgerv.core.diagnostics import Diagnostic, InputError
from edgerv.core.documents import load_monitors
from edgerv.core.language.spot_worker import add_budget_argument, worker
from edgerv.core.monitor import CompiledMonitor, compile_monitors
from edgerv.core.trace_set import TraceSet, expand
from edgerv.report import print_table, to_json

EXIT_OK, EXIT_VIOLATED, EXIT_INPUT = 0, 1, 2
EXIT_INTERNAL = 70  # sysexits' EX_SOFTWARE: a fault of edgerv's, not of the input or the run


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # type: ignore[override]
        self.print_usage(sys.stderr)
        self.exit(EXIT_INPUT, f"{self.prog}: error: {message}\n")


def _report(diagnostics: Sequence[Diagnostic]) -> None:
    for d in diagnostics:
        print(d.render(), file=sys.stderr)


def load_compiled(path: str) -> list[CompiledMonitor]:
    """Load and compile the monitors of a file or directory, printing warnings."""
    compiled, warnings = compile_monitors(load_monitors(path))
    _report(warnings)
    return compiled


def _emit(results: list[MonitorResult], as_json: bool) -> None:
    if as_json:
        print(to_json(results))
    else:
        print_table(results, sys.stdout)


def cmd_check(args: argparse.Namespace) -> int:
    worker.budget = args.synthesis_budget
    try:
        trace = TraceSet(expand([Path(p) for p in args.traces]))
    except InputError as exc:
        _report(exc.diagnostics)
        return EXIT_INPUT
    try:  # the process may end without its teardown: the trace's temporary files go here
        try:
            trace.open()  # first: a bag's own message definitions serve the monitors' types
            monitors = load_compiled(args.monitors)
            run = CheckRun(monitors)
            trace.ends_needed = run.clocked
            total = trace.inspect(run.topics)
            type_errors = check_types(monitors, trace.msgtypes)
            if type_errors:
                raise InputError(type_errors)
        except InputError as exc:
            _report(exc.diagnostics)
            return EXIT_INPUT
        with _collecting_little():
            return _check(args, run, trace, total)
    finally:
        trace.close()


@contextlib.contextmanager
def _collecting_little() -> Iterator[None]:
    """Python's cycle collector, told that what exists now lives to the end (modules,
    Spot's automata, the monitors: gc.freeze) and to run less often: a check makes a
    dict per message and keeps a few thousand at a time, none in a cycle, and every
    collection walked every object there is (a tenth of a check of 200,000 messages)."""
    threshold = gc.get_threshold()
    gc.freeze()
    gc.set_threshold(max(threshold[0], 10_000), *threshold[1:])
    try:
        yield
    finally:
        gc.set_threshold(*threshold)
        gc.unfreeze()


@contextlib.contextmanager
def _progress_bar(name: str, total: int, trace: TraceSet) -> Iterator[Callable[[int], None]]:
    """A progress bar on the terminal (bytes of a JSON trace, messages of a bag) with the
    events checked per second; the function that advances it."""
    from rich.console import Console
    from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

    started = time.monotonic()
    columns = (
        TextColumn("{task.description}"),
        BarColumn(),
        TextColumn("{task.percentage:>3.0f}%"),
        TextColumn("{task.fields[rate]}"),
        TimeRemainingColumn(),
    )
    with Progress(*columns, console=Console(stderr=True), transient=True) as bar:
        task = bar.add_task(f"checking {Path(name).name}", total=total, rate="")

        def advance(n: int) -> None:
            rate = sum(trace.counts.values()) / max(time.monotonic() - started, 1e-6)
            bar.update(task, advance=n, rate=f"{rate:,.0f} events/s")

        yield advance


def _check(args: argparse.Namespace, run: CheckRun, trace: TraceSet, total: int) -> int:
    """Feed the trace to the monitors and print the verdicts; the exit code."""
    try:
        if sys.stderr.isatty() and total and not args.no_progress:
            with _progress_bar(trace.name, total, trace) as advance:
                run.feed(trace.events(run.topics, advance, run.fields()))
        else:
            run.feed(trace.events(run.topics, fields=run.fields()))
    except InputError as exc:
        _emit(run.finish(trace.end), args.json)
        _report(trace.warnings)
        _report(exc.diagnostics)
        print(
            "edgerv: the trace stopped at that error; the verdicts above cover the events "
            "before it",
            file=sys.stderr,
        )
        return EXIT_INPUT
    results = run.finish(trace.end)
    _emit(results, args.json)
    unread = trace.unread(run.readers())
    _report(trace.warnings + unread)
    if not any(trace.counts.values()):  # a verification tool never passes having read nothing
        print(
            f"edgerv: error: no message of any monitored topic was read from {trace.name}: "
            "nothing was checked",
            file=sys.stderr,
        )
        return EXIT_INPUT
    if unread and args.strict:
        print(
            f"edgerv: error: --strict: {len(unread)} monitored topic(s) had no message",
            file=sys.stderr,
        )
        return EXIT_INPUT
    return (
        EXIT_VIOLATED
        if any(v.verdict == "violated" for r in results for v in r.verdicts)
        else EXIT_OK
    )


def build_parser(command: str | None = None) -> argparse.ArgumentParser:
    """The whole command line, or, for ``command`` "check" (the subcommand about to run),
    the check alone: the others' modules (the handler's, HTTP, ROS) take 50 ms to import,
    a tenth of a check of 200,000 messages, and a check uses none of them."""
    parser = _Parser(prog="edgerv", description="Runtime verification for ROS 2 robots.")
    parser.add_argument("--version", action="version", version=f"edgerv {__version__}")
    parser.add_argument("--debug", action="store_true", help=_DEBUG_HELP)
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    check = sub.add_parser(
        "check",
        help="verify a recorded run (JSON Lines trace or rosbag2 bag)",
        description="Run the monitors over a recorded run. Exit 0: no monitor violated; "
        "1: a monitor was violated; 2: bad input.",
    )
    check.add_argument(
        "monitors", help="a Monitor YAML file (several documents allowed) or a directory of them"
    )
    check.add_argument(
        "traces",
        nargs="+",
        metavar="trace",
        help="a .jsonl trace, or a rosbag2 bag (.mcap, .db3 or its directory), or a "
        "directory of them; several are checked as one run, merged in stamp order",
    )
    check.add_argument("--json", action="store_true", help="print the verdicts as JSON")
    check.add_argument("--no-progress", action="store_true", help="no progress bar")
    check.add_argument(
        "--strict",
        action="store_true",
        help="exit 2 when a monitored topic has no message in the trace (else a warning)",
    )
    add_budget_argument(check)
    check.set_defaults(func=cmd_check)
    if command == "check":
        _add_debug(sub)
        return parser

    from edgerv.handler.main import add_arguments, run

    handler = sub.add_parser(
        "handler",
        help="run the monitors on live ROS 2 traffic (a monitor handler)",
        description="A ROS 2 node that subscribes to the monitors' topics, without changing "
        "the robot's software, and reports verdicts on /edgerv/verdicts, in a "
        "verdict log and as Prometheus metrics.",
    )
    add_arguments(handler)
    handler.set_defaults(func=run)

    from edgerv.handler.ros import replay

    rep = sub.add_parser(
        "replay",
        help="publish a JSON Lines trace as real ROS 2 messages",
        description=replay.__doc__,
    )
    replay.add_arguments(rep)
    rep.set_defaults(func=replay.run)

    from edgerv.control import migrate_command

    mig = sub.add_parser(
        "migrate",
        help="move a monitor from one handler to another",
        description=migrate_command.__doc__,
    )
    migrate_command.add_arguments(mig)
    mig.set_defaults(func=migrate_command.run)

    from edgerv.control import orchestrate_command

    orch = sub.add_parser(
        "orchestrate",
        help="poll handlers and move monitors by the placement policy",
        description=orchestrate_command.__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    orchestrate_command.add_arguments(orch)
    orch.set_defaults(func=orchestrate_command.run)

    from edgerv.handler.ros import types as ros_types

    types = sub.add_parser(
        "types",
        help="build the message types of your own ROS packages for the handler (rosidl)",
        description='edgerv types build DIR...: see docs/handler.md, "Your own message types"',
    )
    ros_types.add_arguments(types)
    _add_debug(sub)
    return parser


_DEBUG_HELP = "on an internal error, print its traceback (exit 70 all the same)"


def _add_debug(sub: argparse._SubParsersAction[_Parser]) -> None:
    """``--debug`` after the command too (``edgerv check --debug ...``); SUPPRESS keeps a
    subcommand's default from overwriting ``edgerv --debug check``'s."""
    for command in sub.choices.values():
        command.add_argument("--debug", action="store_true", default=argparse.SUPPRESS,
                             help=_DEBUG_HELP)  # fmt: skip


def main(argv: Sequence[str] | None = None) -> int:
    """The command line (``argv``: its words, else the process's own)."""
    whole_process = argv is None
    argv = sys.argv[1:] if argv is None else list(argv)
    command = next((word for word in argv if not word.startswith("-")), None)
    args = build_parser(command).parse_args(argv)
    try:
        code: int = args.func(args)
    except KeyboardInterrupt:
        return 130
    except BrokenPipeError:
        return EXIT_OK
    except Exception as exc:  # a fault of edgerv's: never an exit code of the verdicts
        code = internal_error(exc, args.debug)
    if whole_process and args.command == "check":
        _exit_now(code)
    return code


def internal_error(exc: BaseException, debug: bool) -> int:
    """Say in one line (the traceback with ``--debug``) that edgerv failed, not the
    input or the run, and how to report it; :data:`EXIT_INTERNAL`."""
    if debug:
        traceback.print_exception(exc, file=sys.stderr)
    what = str(exc).splitlines()[0][:200] if str(exc) else ""
    again = "" if debug else "run it again with --debug and "
    print(
        f"edgerv: internal error: {type(exc).__name__}{': ' + what if what else ''}\n"
        f"  a fault of edgerv's, not of your input: {again}report the traceback to edgerv's "
        "developers with the command and its files (exit 70)",
        file=sys.stderr,
    )
    return EXIT_INTERNAL


def _exit_now(code: int) -> NoReturn:
    """End the process once its output is out, without the interpreter's teardown (as
    mypy does): it frees every object one by one (Spot's automata, the message type
    store, the verdicts) and collects cycles once more, 40 ms of a 0.6 s check, for
    nothing a finished check needs. (Spot's child process sees its pipe close and ends.)"""
    with contextlib.suppress(BrokenPipeError):  # the reader is gone: nothing to tell it
        sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)


if __name__ == "__main__":
    sys.exit(main())
