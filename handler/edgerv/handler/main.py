"""``edgerv handler``: the monitor handler process.

It loads the monitors of a file or directory (a bad monitor is reported and
skipped; the others run), runs the active ones on live ROS 2 traffic, and
reports verdicts on ``/edgerv/verdicts``, in ``--verdict-log`` and as metrics; its
health and its monitors' on ``/diagnostics``, its log lines on stderr and ``/rosout``.
SIGTERM or SIGINT stops it cleanly: no new messages are taken, every buffered
event is evaluated, the verdict log is flushed, and it exits 0. With ``--drain
SECONDS`` it first runs on (monitors and API) until no monitor is active here
(the operator moves them away: a pod going away hands its monitors over), at
most that long; a second signal ends the wait.
"""

from __future__ import annotations

import argparse
import contextlib
import gc
import logging
import math
import os
import signal
import ssl
import sys
import threading
import time
from pathlib import Path

from edgerv.control.tls import is_loopback, server_context
from edgerv.control.token import Token, TokenFile
from edgerv.core.deadline import MakespanWindow, parse_deadline
from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.documents import MonitorSpec, read_monitors
from edgerv.core.language.spot_worker import add_budget_argument, worker
from edgerv.handler.budget import (
    MemoryBudget,
    container_limit,
    default_budget,
    parse_size,
    physical_memory,
    resident_bytes,
    size_text,
)
from edgerv.handler.clock import SimClock
from edgerv.handler.engine import Engine, VerdictSink
from edgerv.handler.health import DiagnosticsConfig, Health
from edgerv.handler.limits import Limits
from edgerv.handler.outbox import ITEM_BYTES, QUEUED, Outbox, ReactionLane
from edgerv.handler.reading import read
from edgerv.handler.ros import types as ros_types
from edgerv.handler.sinks import VerdictLog, ViolationLines

log = logging.getLogger("edgerv.handler")
EXIT_INPUT = 2
EXIT_INTERNAL = 70
# After SIGTERM (and --drain's wait): what was taken is evaluated for EVALUATE_SECONDS at
# most, the verdicts queued are written until STOP_SECONDS, the reactor's calls get their
# own 5 s (reactor.CLOSE_SECONDS); past STOP_WATCHDOG the process exits 70 whatever holds
# it. The chart's grace period is --drain + 15 s.
EVALUATE_SECONDS = 4.0
STOP_SECONDS = 6.0
STOP_WATCHDOG = 14.0
LANES = 5  # verdict log, violation lines, ROS topics, /diagnostics, reactions
VERDICT_BYTES = 160  # a verdict queued: its tuple, its strings shared with the monitor
GC_YOUNG = 10_000  # allocations (less frees) a young collection (settle_memory)
# How long a thread that wants the GIL waits for one that holds it (Python's default 5 ms):
# the take loop gives the GIL up at every call into rcl, and a busy /diagnostics update of
# 10,000 monitors made each of those waits 5 ms (bench/scale.py's publish-to-verdict p99)
SWITCH_SECONDS = 0.0005


def settle_memory() -> None:
    """Exempt the loaded monitors from the cyclic garbage collector's scans.

    With 10,000 monitors a full collection walks ~400,000 objects and stalls the
    handler for ~130 ms: a latency spike. Monitors live as long as the handler, so
    they are frozen out of the scans; after a change through the API the previous
    generation is collected first, so removed monitors are still reclaimed.

    And the collector runs less often (GC_YOUNG allocations a young collection, not
    Python's 700): a /diagnostics update of 10,000 monitors makes some 200,000 objects
    that live until the next (none in a cycle: freed by their counts), and each one
    set off two full collections of about 30 ms, which stall every thread (the GIL):
    publish-to-verdict's p99 at 10,000 monitors (bench/scale.py).
    """
    gc.unfreeze()
    gc.collect()
    gc.freeze()
    young, *older = gc.get_threshold()
    gc.set_threshold(max(young, GC_YOUNG), *older)


def parse_listen(value: str) -> tuple[str, int]:
    host, sep, port = value.rpartition(":")
    if not sep or not port.isdigit() or not 0 <= int(port) <= 65535:
        raise argparse.ArgumentTypeError(f"'{value}' is not HOST:PORT, e.g. 127.0.0.1:8470")
    return host.strip("[]") or "0.0.0.0", int(port)


def whole_number(text: str) -> int:
    """A count of 1 or more (connections, monitors)."""
    if not (text.isascii() and text.isdigit()) or int(text) < 1:
        raise argparse.ArgumentTypeError(f"'{text}' is not a whole number above 0")
    return int(text)


def time_limit(text: str) -> float:
    """SECONDS above 0, finite (a time limit of the API)."""
    with contextlib.suppress(ValueError):
        if 0 < (value := float(text)) < math.inf:
            return value
    raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds above 0")


def drain_limit(text: str) -> float:
    """SECONDS from 0 to a day."""
    with contextlib.suppress(ValueError):
        if 0 <= (value := float(text)) <= 86400:
            return value
    raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds from 0 to 86400")


def seconds_or_zero(text: str) -> float:
    """SECONDS from 0, finite (0: off, or never)."""
    with contextlib.suppress(ValueError):
        if 0 <= (value := float(text)) < math.inf:
            return value
    raise argparse.ArgumentTypeError(f"'{text}' is not a number of seconds from 0")


def read_token(args: argparse.Namespace) -> Token:
    """The shared control token: --token-file (followed: read again when it changes, as a
    rotated Kubernetes Secret does), else $EDGERV_TOKEN."""
    if args.token_file:
        try:
            return TokenFile(args.token_file)
        except OSError as exc:
            raise InputError(
                [Diagnostic(Location(args.token_file), f"cannot read the token: {exc.strerror}")]
            ) from None
        except (ValueError, UnicodeDecodeError):
            raise InputError(
                [Diagnostic(Location(args.token_file), "the token file is empty or not text")]
            ) from None
    return os.environ.get("EDGERV_TOKEN") or None


def serving_tls(args: argparse.Namespace) -> ssl.SSLContext | None:
    """The API's TLS context from --tls-cert and --tls-key (None: plain HTTP, which only a
    loopback address or --plain-http allows)."""
    if bool(args.tls_cert) != bool(args.tls_key):
        given, missing = ("--tls-cert", "--tls-key")
        if args.tls_key:
            given, missing = missing, given
        raise InputError([Diagnostic(Location(given), f"given without {missing}: give both")])
    if args.tls_cert:
        if args.plain_http:
            raise InputError(
                [Diagnostic(Location("--plain-http"), "given with --tls-cert: choose one")]
            )
        return server_context(args.tls_cert, args.tls_key)
    if args.listen and not args.plain_http and not is_loopback(args.listen[0]):
        raise InputError(
            [
                Diagnostic(
                    Location("--listen"),
                    f"{args.listen[0]} is not a loopback address and no certificate is "
                    "given: serve HTTPS with --tls-cert and --tls-key (or pass --plain-http "
                    "on a trusted lab network)",
                )
            ]
        )
    return None


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", required=True, help="this handler's name (e.g. the machine's)")
    p.add_argument(
        "--monitors",
        metavar="FILE_OR_DIR",
        help="Monitor YAML documents: a file or a directory of .yaml files (without it, "
        "the handler starts with none: they come through the API, e.g. from the operator)",
    )
    p.add_argument(
        "--active",
        default="all",
        metavar="all|none|m1,m2",
        help="which monitors run here; the others are defined but idle",
    )
    p.add_argument(
        "--listen",
        type=parse_listen,
        metavar="HOST:PORT",
        help="serve the HTTP API (/healthz, /metrics, /v1/monitors) here",
    )
    p.add_argument("--verdict-log", metavar="FILE", help="append verdicts here, one JSON per line")
    p.add_argument(
        "--token-file",
        metavar="FILE",
        help="the control API's bearer token (default: $EDGERV_TOKEN)",
    )
    p.add_argument(
        "--insecure",
        action="store_true",
        help="serve the control API without a token (never on a shared network)",
    )
    p.add_argument(
        "--tls-cert",
        metavar="FILE",
        help="serve the API over HTTPS with this certificate (PEM, its chain after it)",
    )
    p.add_argument("--tls-key", metavar="FILE", help="the certificate's private key (PEM)")
    p.add_argument(
        "--plain-http",
        action="store_true",
        help="serve plain HTTP on an address other than loopback (the token and the "
        "handoff's bundles cross the network in clear: a trusted lab network only)",
    )
    p.add_argument(
        "--flush-after",
        type=float,
        default=0.5,
        metavar="SECONDS",
        help="release a partly filled sort buffer after this long (default 0.5)",
    )
    p.add_argument(
        "--reorder-window",
        type=float,
        default=0.02,
        metavar="SECONDS",
        help="order messages of different topics by timestamp within this window before "
        "evaluating them (default 0.02; 0 turns it off)",
    )
    p.add_argument(
        "--deadline",
        metavar="TOPIC=DURATION",
        help="the robot's real-time task publishes its outputs on TOPIC, each stamped "
        "(header.stamp) with the capture of its input; measure its makespan (publication "
        "minus stamp) against DURATION (e.g. /cmd_vel=125ms) and report it in /v1/load; "
        "a relative TOPIC (cmd_vel=125ms) is the robot's: in the ROS namespace of the "
        "robot whose monitors this handler runs (a fleet's edge handler)",
    )
    add_budget_argument(p)
    p.add_argument(
        "--memory-budget",
        type=parse_size,
        metavar="SIZE",
        help="the memory this handler may take, e.g. 1GiB: the process itself, its "
        "verdict queues, request bodies, a snapshot bundle, and every monitor's buffers "
        "as they will fill; a monitor that would pass it is refused (default: half the "
        "container's memory limit, else of the machine's memory, at least 512 MiB)",
    )
    given = Limits()
    p.add_argument(
        "--max-monitors",
        type=whole_number,
        default=given.monitors,
        metavar="N",
        help="define at most N monitors here, active or not: more from --monitors are "
        f"refused at start, more through the API get 403 (default {given.monitors:,}; "
        "each idle one takes ~10 KiB)",
    )
    p.add_argument(
        "--api-max-connections",
        type=whole_number,
        default=given.connections,
        metavar="N",
        help="serve at most N connections a request with the token came on; one more "
        "such request closes the one idle longest, or is answered 503 when each is busy "
        f"(default {given.connections})",
    )
    p.add_argument(
        "--api-max-pending",
        type=whole_number,
        default=given.pending,
        metavar="N",
        help="keep at most N connections that have not shown the token (new ones, and "
        "those of /healthz and /metrics); one more closes the one that waited longest of "
        f"the address that holds the most (default {given.pending})",
    )
    p.add_argument(
        "--api-read-timeout",
        type=time_limit,
        default=given.read_seconds,
        metavar="SECONDS",
        help="close a connection whose request (head and body) has not all arrived this "
        "long after its first byte, or whose answer waits this long to be read "
        f"(default {given.read_seconds:g})",
    )
    p.add_argument(
        "--api-idle-timeout",
        type=time_limit,
        default=given.idle_seconds,
        metavar="SECONDS",
        help="close a kept-alive connection that sends no request for this long "
        f"(default {given.idle_seconds:g})",
    )
    p.add_argument(
        "--drain",
        type=drain_limit,
        default=0.0,
        metavar="SECONDS",
        help="on SIGTERM, first run on until no monitor is active here (moved away by the "
        "operator), at most this long (default 0: stop at once)",
    )
    given_diagnostics = DiagnosticsConfig()
    p.add_argument(
        "--diagnostics-period",
        type=seconds_or_zero,
        default=given_diagnostics.period,
        metavar="SECONDS",
        help="publish the handler's and its monitors' statuses on /diagnostics this often, "
        f"and at once when a level changes (default {given_diagnostics.period:g}; 0: off)",
    )
    p.add_argument(
        "--diagnostics-hold",
        type=seconds_or_zero,
        default=given_diagnostics.hold,
        metavar="SECONDS",
        help="a monitor's violation shows as ERROR on /diagnostics this long "
        f"(default {given_diagnostics.hold:g})",
    )
    p.add_argument(
        "--diagnostics-stale",
        type=seconds_or_zero,
        default=given_diagnostics.stale,
        metavar="SECONDS",
        help="a monitor that had no event this long shows as STALE on /diagnostics "
        f"(default {given_diagnostics.stale:g}; 0: never)",
    )
    p.add_argument(
        "--use-sim-time",
        action="store_true",
        help="take ROS time from /clock (rosgraph_msgs/msg/Clock), as a ROS node with "
        "use_sim_time does: a simulation's, or `edgerv replay`'s; timed monitors follow it",
    )
    p.add_argument(
        "--quiet-violations",
        action="store_true",
        help="print no line per violation (by default one on stderr and /rosout, at most "
        "one a second per monitor); the verdicts still go to their topics and logs",
    )
    p.add_argument(
        "--types-cache",
        metavar="DIR",
        help="where message types of your own packages (not installed: found as .msg files "
        "where `edgerv check` finds them) are built at their first use, once (default "
        "$EDGERV_TYPES_CACHE, else ~/.cache/edgerv/types; none: build nothing): see "
        'docs/handler.md, "Your own message types"',
    )
    p.add_argument("--log-level", default="info", choices=["debug", "info", "warning", "error"])


def load(engine: Engine, specs: list[MonitorSpec], active: set[str], most: int) -> list[Diagnostic]:
    """Define the monitors of --monitors, at most ``most`` of them (--max-monitors): a
    monitor beyond is refused at its place, with the number of those after it."""
    diagnostics = []
    for i, spec in enumerate(specs):
        if len(engine.slots) >= most:
            more = f" and the {len(specs) - i - 1} after it" if i + 1 < len(specs) else ""
            refused = (
                f"monitor '{spec.name}'{more} not loaded: this handler holds at most {most} "
                "(--max-monitors): raise it, or run the others on another handler"
            )
            diagnostics.append(Diagnostic(spec.location, refused))
            break
        try:
            engine.put(engine.compile(spec), active=spec.name in active)
        except InputError as exc:
            diagnostics += exc.diagnostics
    return diagnostics


DRAIN_LINGER = 2.0  # seconds a drained handler stays up: its last answers are read


def _busy(engine: Engine) -> list[str]:
    """The monitors active here or in a handoff."""
    return [m.name for m in read(engine).monitors if m.active or m.handoff]


def drain(engine: Engine, seconds: float, hurry: threading.Event) -> None:
    """Run on until no monitor is active here or in a handoff (moved away by whoever
    drives the handoffs: the operator, for a pod going away), ``seconds`` at most."""
    until = time.monotonic() + seconds
    busy = _busy(engine)
    if not busy:
        return
    log.info("draining: up to %gs for %d monitor(s) to move away", seconds, len(busy))
    while busy and not hurry.wait(0.2):
        busy = _busy(engine)
        if time.monotonic() >= until:
            log.warning(
                "drain: %d monitor(s) still here after %gs: %s (their state ends here)",
                len(busy),
                seconds,
                ", ".join(sorted(busy)[:10]) + (" ..." if len(busy) > 10 else ""),
            )
            return
    if not busy:
        log.info("drained: no monitor runs here")
        hurry.wait(DRAIN_LINGER)  # whoever moved them reads their final counts meanwhile


def memory_budget(args: argparse.Namespace) -> MemoryBudget:
    """--memory-budget, else the default from the container's limit, shared out."""
    if args.memory_budget is not None:
        total, origin = args.memory_budget, "--memory-budget"
    else:
        limit = container_limit()
        total = default_budget(limit, physical_memory())
        where = "the container's" if limit is not None else "the machine's"
        origin = f"the default: half {where} memory, at least 512 MiB"
    queues = LANES * QUEUED * (ITEM_BYTES + VERDICT_BYTES)
    return MemoryBudget.plan(total, Limits(), queues, resident_bytes(), origin)


def watchdog(at: float) -> None:
    """A thread that ends the process (exit 70: an internal error, never 0 or 1) if the
    ordered shutdown has not ended by ``at`` (monotonic): a pod's grace period is
    bounded, and SIGKILL would lose the verdict log's last lines without a word."""

    def wait() -> None:
        time.sleep(max(0.0, at - time.monotonic()))
        log.error("stopping took longer than %g s: exiting now", STOP_WATCHDOG)
        logging.shutdown()
        os._exit(EXIT_INTERNAL)

    threading.Thread(target=wait, name="edgerv-stop-watchdog", daemon=True).start()


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(
        level=args.log_level.upper(),
        stream=sys.stderr,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    worker.budget = args.synthesis_budget
    try:
        token = read_token(args)
        deadline = parse_deadline(args.deadline) if args.deadline is not None else None
    except InputError as exc:
        print(exc, file=sys.stderr)
        return EXIT_INPUT
    try:
        tls = serving_tls(args)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return EXIT_INPUT
    if args.listen and token is None and not args.insecure:
        print(
            "edgerv handler: error: refusing to serve the control API without a token: set "
            "EDGERV_TOKEN or --token-file (or pass --insecure on a trusted network)",
            file=sys.stderr,
        )
        return EXIT_INPUT
    specs, diagnostics = read_monitors(args.monitors) if args.monitors else ([], [])
    if args.monitors and not Path(args.monitors).exists():
        print("\n".join(d.render() for d in diagnostics), file=sys.stderr)
        return EXIT_INPUT
    if not args.monitors and not args.listen:
        print(
            "edgerv handler: error: without --monitors the monitors come through the API: "
            "give --listen HOST:PORT",
            file=sys.stderr,
        )
        return EXIT_INPUT
    names = {s.name for s in specs}
    if args.active in ("all", "none"):
        active = names if args.active == "all" else set()
    else:
        active = {n.strip() for n in args.active.split(",") if n.strip()}
        unknown = sorted(active - names)
        if unknown:
            diagnostics.append(
                Diagnostic(Location("--active"), f"no monitor named {', '.join(unknown)}")
            )
    from edgerv.handler.api import ControlApi
    from edgerv.handler.metrics import build_registry
    from edgerv.handler.ros import node as ros_node  # ROS from here on: `check` needs none
    from edgerv.handler.ros.messages import type_problem

    ros_types.configure(args.types_cache)  # types of the robot's own, built at first use
    ros_node.init_ros()
    budget = memory_budget(args)
    if (problem := budget.startup_problem()) is not None:
        print(f"edgerv handler: error: {budget.origin}: {problem}", file=sys.stderr)
        return EXIT_INPUT
    outbox = Outbox(args.name)  # each sink a lane: a bounded queue and a thread
    sinks: list[VerdictSink] = [outbox]
    verdict_log = VerdictLog(args.verdict_log) if args.verdict_log else None
    if verdict_log:
        outbox.add("verdict-log", verdict_log, exact=True)  # every verdict: never coalesced
    window = max(0.0, args.reorder_window)
    clock = SimClock(args.flush_after) if args.use_sim_time else None  # else the system's
    engine = Engine(
        args.name,
        sinks,
        flush_after=args.flush_after,
        type_check=type_problem,
        reorder_window=window,
        deadline=(
            MakespanWindow(deadline.topic, deadline.budget_ns, relative=deadline.relative)
            if deadline
            else None
        ),
        clock=clock,
    )
    lines = None
    if not args.quiet_violations:  # a line per violation on stderr and /rosout
        lines = ViolationLines(
            lambda m: s.compiled.spec.topics if (s := engine.slots.get(m)) else ()
        )
        outbox.add("violation-lines", lines)
    health = Health(
        args.name,
        DiagnosticsConfig(args.diagnostics_period, args.diagnostics_hold, args.diagnostics_stale),
    )
    ros = ros_node.HandlerNode(
        engine, args.name, reorder_window=window, health=health, outbox=outbox
    )
    ros.rosout.forward(logging.getLogger("edgerv"))  # /rosout, besides stderr
    outbox.add("ros-topics", ros.verdicts)  # /edgerv/verdicts and /edgerv/verdict
    if ros.diagnostics is not None:
        outbox.add("diagnostics", health)  # notes violations as they come: published at once
    engine.matched = ros.subscriptions.matched
    from edgerv.handler.ros.reactor import Reactor

    reactor = Reactor(args.name, engine.note_reaction)  # spec.onViolation
    reactions = ReactionLane(reactor, args.name)
    engine.reactor = reactions
    engine.budget = budget

    def refuse_to_start() -> int:
        """Close what was opened (nothing was evaluated yet), for an input error."""
        now = time.monotonic()
        reactions.close(now)
        reactor.close()
        outbox.close(now)
        ros.close()
        return EXIT_INPUT

    diagnostics += load(engine, specs, active, args.max_monitors)
    for d in diagnostics:
        print(d.render(), file=sys.stderr)
    if budget.refused:  # the monitors given do not fit: a configuration to fix, not to run
        print(
            f"edgerv handler: error: {budget.refused} monitor(s) of --monitors do not fit "
            f"the memory budget ({size_text(budget.total)}, {budget.origin}): not starting",
            file=sys.stderr,
        )
        return refuse_to_start()
    if any(d.severity == "error" for d in diagnostics):
        log.error(
            "%d problem(s) above: those monitors are not loaded; the others run",
            sum(d.severity == "error" for d in diagnostics),
        )

    settle_memory()
    sys.setswitchinterval(SWITCH_SECONDS)
    stop = threading.Event()

    def on_change() -> None:  # the API added, replaced or removed monitors
        settle_memory()
        ros.wake()

    def on_signal(signum: int, _frame: object) -> None:
        if stop.is_set():
            log.info("%s: stopping now", signal.Signals(signum).name)
            hurry.set()
            return
        log.info("%s: stopping", signal.Signals(signum).name)
        stop.set()

    hurry = threading.Event()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)

    api = None
    if args.listen:
        api = ControlApi(
            engine,
            build_registry(engine, lambda: dict(ros.subscriptions.qos_problems), outbox, budget),
            token,
            on_change=on_change,
            on_routes=ros.wake,
            limits=budget.limits(
                Limits(
                    connections=args.api_max_connections,
                    pending=args.api_max_pending,
                    read_seconds=args.api_read_timeout,
                    idle_seconds=args.api_idle_timeout,
                    monitors=args.max_monitors,
                )
            ),
        )
        try:
            host, port = args.listen
            api.start(host, port, tls=tls)
        except OSError as exc:
            print(
                f"edgerv handler: error: cannot listen on {args.listen[0]}:{args.listen[1]}: "
                f"{exc.strerror}",
                file=sys.stderr,
            )
            return refuse_to_start()
    scheduler_stop = threading.Event()
    scheduler = threading.Thread(
        target=engine.run_scheduler, args=(scheduler_stop,), name="edgerv-scheduler", daemon=True
    )
    scheduler.start()
    ros.start(on_failure=stop.set)
    ros.take.ready.wait(timeout=10)
    reading = read(engine)
    log.info(
        "handler %s ready: %d of %d monitors active%s",
        args.name,
        len(reading.active()),
        len(reading.monitors),
        f", API on port {api.port}" if api else "",
    )
    while not stop.wait(0.5):
        pass
    if args.drain > 0 and api is not None and not ros.take.failed:
        drain(engine, args.drain, hurry)
    # Ordered shutdown: take nothing more, evaluate what was taken, then close the outputs;
    # each within its time, whatever is queued (a verdict storm's backlog included).
    stopping = time.monotonic()
    watchdog(stopping + STOP_WATCHDOG)
    evaluated_by, written_by = stopping + EVALUATE_SECONDS, stopping + STOP_SECONDS
    outbox.until = evaluated_by  # the verdict log's lane: the scheduler waits no longer
    ros.stop()
    scheduler_stop.set()
    engine.wake()
    scheduler.join(timeout=max(0.1, evaluated_by - time.monotonic()))
    engine.drain(evaluated_by)
    reactions.close(written_by)
    outbox.close(written_by)
    if lines is not None:
        lines.close()  # the violations held back that no line followed
    reactor.close()  # after the last violations' reactions
    if api:
        api.stop()
    if verdict_log:
        verdict_log.close()
    ros.close()
    ros_node.shutdown_ros()
    log.info("handler %s stopped", args.name)
    return 1 if ros.take.failed else 0
