"""``edgerv orchestrate``: poll handlers and move monitors by the placement policy, as
an :class:`~edgerv.control.orchestrate.Orchestrator` in rounds: each action one JSON line
on stdout, why a round moves nothing on stderr. Authenticates with ``EDGERV_TOKEN`` like
the handlers.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import fields

from edgerv.control.client import address_problem
from edgerv.control.cpu_budget import FLOOR_CORES, CpuBudget, CpuBudgetError, DockerCpuBudget
from edgerv.control.migrate_command import (
    HelpFormatter,
    add_client_arguments,
    client_tls,
    finite,
    seconds_above_zero,
    seconds_from_zero,
)
from edgerv.control.orchestrate import BudgetLever, Idle, Orchestrator, Target, build_reports
from edgerv.control.placement import PolicyConfig, PolicyConfigError, tier_latencies
from edgerv.core.diagnostics import Diagnostic, InputError, Location
from edgerv.core.planner import BudgetConfig
from edgerv.core.robots import ROBOT_NAME


def parse_handlers(text: str) -> list[Target]:
    """``edge=HOST:PORT,cloud=HOST:PORT`` (a tier may have several handlers); a fleet's
    robot handlers as ``edge@amr-7=HOST:PORT`` (it runs that robot's instances only; a
    handler named without a robot is shared: docs/protocol.md, "Fleet")."""
    targets: list[Target] = []
    for i, item in enumerate(p.strip() for p in text.split(",")):
        where, eq, address = (part.strip() for part in item.partition("="))
        tier, at, robot = (part.strip() for part in where.partition("@"))
        problem = ""
        if not eq or not tier or not address:
            problem = f"item {i + 1} '{item}' is not TIER=HOST:PORT or TIER@ROBOT=HOST:PORT"
        elif at and not ROBOT_NAME.match(robot):
            problem = (
                f"item {i + 1} '{item}': '{robot}' is not a robot's name (a lower-case "
                "letter, then letters, digits and '-')"
            )
        elif bad := address_problem(address):
            problem = f"item {i + 1} '{item}': {bad}"
        elif any(t.address == address for t in targets):
            problem = f"item {i + 1} '{item}': {address} is listed already"
        if problem:
            raise InputError(
                [
                    Diagnostic(
                        Location("--handlers"),
                        problem,
                        hint="e.g. --handlers edge=10.0.0.2:8080,cloud=10.0.0.9:8080",
                    )
                ]
            )
        targets.append(Target(tier, address, robot or None))
    return targets


def parse_pairs(text: str, flag: str) -> dict[str, float]:
    """``edge=0,cloud=40``: a finite number from 0 for each name (an error at ``flag``)."""
    try:
        return tier_latencies(text)
    except ValueError as exc:
        raise InputError([Diagnostic(Location(flag), str(exc))]) from None


positive_number = finite("a number above 0", zero=False)  # a ratio, a fraction


DESCRIPTION = """\
Poll the handlers' load reports (GET /v1/load) every --interval seconds (at once
when a handler measuring a deadline misses it while all were met), ask the
placement policy where each monitor should run, and do it: start a monitor that
runs nowhere, move the others by the handoff of edgerv migrate. Each action is
printed as one JSON line on stdout. A round that moves nothing says why on
stderr, once each time the reason changes ("edgerv orchestrate: nothing to
move: ..."). A handler that does not answer is left out of that round, and no
monitor is started that round (it may run on the silent one). A move that ends
unsettled (a handler did not answer, so where its monitors run is not
confirmed) is printed with "ok": false and "unsettled"; its monitors are settled
at the start of each later round, and not moved again until that succeeds.
With --budget-container, each round also sets the CPU budget (CFS quota) of
the edge handler's Docker container: lowered when its deadline is at risk,
raised while it is calm and the robot's tasks leave headroom, each change one
JSON line ("budget", "from", in cores); see docs/protocol.md, "What it plans".
Authenticates with the token in EDGERV_TOKEN, as the handlers do.
"""


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.description = DESCRIPTION
    p.formatter_class = HelpFormatter
    add_client_arguments(p)
    p.add_argument(
        "--handlers",
        required=True,
        metavar="TIER=HOST:PORT,...",
        help="the handlers and their tiers, e.g. edge=10.0.0.2:8080,cloud=10.0.0.9:8080 "
        "(HTTPS unless loopback: --ca-file; TIER=http://HOST:PORT asks for plain HTTP); "
        "a fleet's robot's handler: TIER@ROBOT=HOST:PORT, e.g. edge@amr-7=10.0.0.2:8080 (it "
        "runs that robot's instances only; one without @ROBOT is shared)",
    )
    p.add_argument(
        "--tiers",
        metavar="LOW,...,HIGH",
        help="the tiers in order, closest to the robot first (default: as --handlers lists them)",
    )
    p.add_argument(
        "--tier-latency",
        default="",
        metavar="TIER=MS,...",
        help="each tier's latency from the robot in milliseconds, for placement.maxLatencyMs "
        "(default: 0 for each)",
    )
    p.add_argument(
        "--interval",
        type=seconds_above_zero,
        default=1.0,
        metavar="SECONDS",
        help="between two rounds; a missed deadline ends it when every deadline was met "
        "(GET /v1/deadline)",
    )
    p.add_argument(
        "--calm",
        type=seconds_from_zero,
        default=30.0,
        metavar="SECONDS",
        help="how long the handler below must be calm before a monitor comes back down",
    )
    p.add_argument(
        "--cooldown",
        type=seconds_from_zero,
        default=60.0,
        metavar="SECONDS",
        help="a monitor comes back down no sooner than this after its last move, doubled "
        "after each bounce",
    )
    defaults = {f.name: f.default for f in fields(PolicyConfig)}
    p.add_argument(
        "--max-moves-down",
        type=int,
        default=defaults["max_moves_down"],
        metavar="N",
        help="monitors brought down a tier per round below a calm handler",
    )
    p.add_argument(
        "--deadline-high",
        type=positive_number,
        default=defaults["deadline_high"],
        metavar="RATIO",
        help="deadline pressure: a handler's p95 makespan / budget at or above this "
        "(handlers started with --deadline)",
    )
    p.add_argument(
        "--deadline-low",
        type=positive_number,
        default=defaults["deadline_low"],
        metavar="RATIO",
        help="calm needs p95 makespan / budget at or below this",
    )
    p.add_argument(
        "--deadline-shed",
        type=positive_number,
        default=defaults["deadline_shed"],
        metavar="FRACTION",
        help="under deadline pressure, move at least this share of the handler's movable "
        "event load up a tier, busiest first",
    )
    p.add_argument(
        "--deadline-wait",
        type=seconds_from_zero,
        default=defaults["deadline_wait"],
        metavar="SECONDS",
        help="after such a move, leave that handler's deadline alone this long",
    )
    p.add_argument(
        "--plan",
        action=argparse.BooleanOptionalAction,
        default=defaults["planner"],
        help="size deadline moves up and home by the planner from the monitors' measured "
        "costs, one handoff each (docs/protocol.md, 'What it plans'); --no-plan: the rule "
        "above always",
    )
    p.add_argument(
        "--plan-margin",
        type=finite("a fraction from 0 below 1", zero=True),
        default=defaults["planner_margin"],
        metavar="FRACTION",
        help="the share of the edge's headroom a plan leaves free, up and home",
    )
    p.add_argument(
        "--budget-container",
        metavar="CONTAINER[=HOST:PORT]",
        help="set the CPU budget of this Docker container, the edge handler's, each round "
        "(DOCKER_HOST's daemon, else the local one; needs pip install 'edgerv[planner]'); "
        "=HOST:PORT names the handler of --handlers it runs, needed when the lowest tier "
        "has several",
    )
    p.add_argument(
        "--budget-floor",
        type=positive_number,
        metavar="CORES",
        help=f"the least budget set (default {FLOOR_CORES:g}): the handler keeps answering",
    )
    p.add_argument(
        "--budget-ceiling",
        type=positive_number,
        metavar="CORES",
        help="the most budget set (default: the machine's cores)",
    )
    p.add_argument(
        "--budget-hysteresis",
        type=finite("a fraction from 0 below 1", zero=True),
        metavar="FRACTION",
        help="a new budget within this share of the budget in force is not set (default 0.1)",
    )
    p.add_argument(
        "--timeout",
        type=seconds_above_zero,
        default=30.0,
        metavar="SECONDS",
        help="per migration; after a failure, as long again to settle it",
    )
    p.add_argument("--once", action="store_true", help="one round (after a first poll), then exit")


def config_from(args: argparse.Namespace, targets: Sequence[Target]) -> PolicyConfig:
    tiers = (
        [t.strip() for t in args.tiers.split(",") if t.strip()]
        if args.tiers
        else list(dict.fromkeys(t.tier for t in targets))
    )
    unknown = sorted({t.tier for t in targets} - set(tiers))
    if unknown:
        raise InputError(
            [
                Diagnostic(
                    Location("--handlers"),
                    f"tier {', '.join(unknown)} is not in --tiers {','.join(tiers)}",
                )
            ]
        )
    latency = parse_pairs(args.tier_latency, "--tier-latency")
    strangers = sorted(set(latency) - set(tiers))
    if strangers:
        raise InputError(
            [
                Diagnostic(
                    Location("--tier-latency"),
                    f"tier {', '.join(strangers)} is not one of the tiers {','.join(tiers)}",
                )
            ]
        )
    try:
        return PolicyConfig(
            tiers=tuple(tiers),
            tier_latency_ms=latency,
            calm_seconds=args.calm,
            cooldown_seconds=args.cooldown,
            max_moves_down=args.max_moves_down,
            deadline_high=args.deadline_high,
            deadline_low=args.deadline_low,
            deadline_shed=args.deadline_shed,
            deadline_wait=args.deadline_wait,
            planner=args.plan,
            planner_margin=args.plan_margin,
        )
    except PolicyConfigError as exc:
        flags = {"planner_margin": "--plan-margin"}  # (a setting whose flag is not its name)
        flag = flags.get(exc.setting, "--" + exc.setting.replace("_", "-"))
        said = str(exc)
        if exc.setting == "deadline_low":  # the two marks: name the one given
            marks = f"--deadline-low {args.deadline_low:g}, --deadline-high {args.deadline_high:g}"
            given_high = args.deadline_high != PolicyConfig.deadline_high
            if given_high and args.deadline_low == PolicyConfig.deadline_low:
                flag = "--deadline-high"
            said = f"{said} ({marks})"
        raise InputError([Diagnostic(Location(flag), said)]) from None
    except ValueError as exc:
        raise InputError([Diagnostic(Location("--tiers"), str(exc))]) from None


def parse_budget_container(text: str, targets: Sequence[Target], lowest: str) -> tuple[str, Target]:
    """``CONTAINER[=HOST:PORT]``: the container and the handler of ``targets`` it runs
    (without HOST:PORT: the one handler of the ``lowest`` tier)."""

    def wrong(problem: str) -> InputError:
        hint = "e.g. --budget-container edgerv-edge, or edgerv-edge=10.0.0.2:8080"
        return InputError([Diagnostic(Location("--budget-container"), problem, hint=hint)])

    container, eq, address = (part.strip() for part in text.partition("="))
    if not container or (eq and not address):
        raise wrong(f"'{text}' is not CONTAINER or CONTAINER=HOST:PORT")
    if eq:
        named = [t for t in targets if t.address == address]
        if not named:
            listed = ", ".join(t.address for t in targets)
            raise wrong(f"{address} is not one of --handlers ({listed})")
        return container, named[0]
    edge = [t for t in targets if t.tier == lowest]
    if len(edge) != 1:
        listed = ", ".join(t.address for t in edge) or "none"
        raise wrong(
            f"the lowest tier, {lowest}, has {len(edge)} handlers ({listed}): name the one "
            f"in container {container}, {container}=HOST:PORT"
        )
    return container, edge[0]


def docker_budget(container: str, floor: float) -> CpuBudget:
    """The budget of a Docker container of the environment's daemon (``DOCKER_HOST``)."""
    return DockerCpuBudget(container, floor=floor)


def budget_lever(
    args: argparse.Namespace,
    targets: Sequence[Target],
    config: PolicyConfig,
    budget_of: Callable[[str, float], CpuBudget] | None = None,
) -> BudgetLever | None:
    """The lever of ``--budget-container`` (None without it); ``budget_of(container,
    floor)`` the container's budget, by default a
    :class:`~edgerv.control.cpu_budget.DockerCpuBudget`. An :class:`InputError` for a flag
    that is wrong, a container not found, or a daemon that does not answer."""
    given = [
        flag
        for flag in ("--budget-floor", "--budget-ceiling", "--budget-hysteresis")
        if getattr(args, flag[2:].replace("-", "_")) is not None
    ]
    if args.budget_container is None:
        if given:
            raise InputError(
                [Diagnostic(Location(given[0]), "needs --budget-container: whose budget?")]
            )
        return None
    container, target = parse_budget_container(args.budget_container, targets, config.tiers[0])
    floor = FLOOR_CORES if args.budget_floor is None else args.budget_floor
    try:
        budget = (budget_of or docker_budget)(container, floor)
    except CpuBudgetError as exc:
        raise InputError([Diagnostic(Location("--budget-container"), str(exc))]) from None
    except ValueError as exc:  # the floor above the machine's cores
        raise InputError([Diagnostic(Location("--budget-floor"), str(exc))]) from None
    ceiling = budget.ceiling if args.budget_ceiling is None else args.budget_ceiling
    try:
        bounds = BudgetConfig(
            floor=floor,
            ceiling=min(ceiling, budget.ceiling),
            hysteresis=0.1 if args.budget_hysteresis is None else args.budget_hysteresis,
            wait=config.deadline_wait,
        )
    except ValueError as exc:
        flag = "--budget-ceiling" if args.budget_ceiling is not None else "--budget-floor"
        raise InputError(
            [Diagnostic(Location(flag), f"{exc} (the machine has {budget.ceiling:g} cores)")]
        ) from None
    return BudgetLever(budget, target, bounds, container)


def run(args: argparse.Namespace) -> int:
    try:
        targets = parse_handlers(args.handlers)
        config = config_from(args, targets)
        tls = client_tls(args)
        lever = budget_lever(args, targets, config)
    except InputError as exc:
        print(exc, file=sys.stderr)
        return 2

    def say(idle: Idle) -> None:
        print(f"edgerv orchestrate: nothing to move: {idle.text}", file=sys.stderr, flush=True)

    orchestrator = Orchestrator(
        targets,
        config,
        os.environ.get("EDGERV_TOKEN"),
        args.timeout,
        tls=tls,
        on_idle=say,
        levers=[] if lever is None else [lever],
    )
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    if args.once:  # two polls: the first gives the counters the rates start from
        build_reports(orchestrator.poll(), orchestrator.previous)
        time.sleep(min(args.interval, 1.0))
    while True:
        for record in orchestrator.round():
            print(json.dumps(record), flush=True)
        if args.once or orchestrator.wait(args.interval, stop) == "stopped":
            return 0
