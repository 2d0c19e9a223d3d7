"""The operator's Kopf handlers: thin glue over :mod:`~edgerv_operator.documents`,
:mod:`~edgerv_operator.placement` and :mod:`~edgerv_operator.status`.

A Monitor resource is defined on every handler of the cluster (the pods of the
chart's DaemonSet, one per node, host networking) and runs on one: where it runs
already, else a ready handler of its home tier (``placement.tier``, default the
lowest), else of the nearest tier above, the least loaded there
(:func:`~edgerv_operator.placement.choose`: the placement policy's rule). What
the operator keeps between calls lives in Kopf's ``memo`` (an :class:`Operator`);
the nodes' tiers come from a Kopf index, kept by watching; the handler pods from the
index of a second Kopf operator that watches them in their own namespace only
(:mod:`~edgerv_operator.pods`, started and stopped with this one).

Every few seconds (the Monitors' status timers; the first one due does it for
all) the operator asks each handler once for all its monitors (the *survey*),
then tends the cluster: monitors on a handler pod that is going away move to
another by the handoff (a drain), and the placement policy of ``edgerv
orchestrate`` runs one round. Moves are made one at a time (one lock): a tier
edit, a drain and a placement round never act on a monitor at once
(docs/protocol.md, "The operator"). Run it with ``edgerv-operator`` (the image does;
:mod:`edgerv_operator.__main__`), or ``kopf run -m edgerv_operator.handlers``.
"""

from __future__ import annotations

import datetime
import functools
import json
import logging
import threading
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import kopf

from edgerv.control.client import (
    ApiError,
    HandlerClient,
    Invalid,
    NotFound,
    Unauthorized,
)
from edgerv.control.migrate import migrate, settle
from edgerv.control.orchestrate import Orchestrator, Target
from edgerv.control.placement import HandlerReport
from edgerv.control.wire import MonitorReport
from edgerv.core.robots import Fleet, fleet_of, may_host
from edgerv_operator.budget import Levers, core_api
from edgerv_operator.config import ConfigError, OperatorConfig
from edgerv_operator.constants import FINALIZER, MONITORS
from edgerv_operator.documents import (
    HandlerPod,
    document_text,
    handler_name,
    instance_document,
    monitor_document,
    read,
)
from edgerv_operator.placement import (
    change,
    choose,
    destination,
    drained,
    placement_of,
    tier_of,
)
from edgerv_operator.pods import PodFacts, PodWatch
from edgerv_operator.pods import login as pods_login
from edgerv_operator.status import (
    FLEET_FIELDS,
    Event,
    Survey,
    fleet_refreshed,
    invalid,
    moved,
    refreshed,
    robot_refreshed,
)

log = logging.getLogger("edgerv.operator")
STATUS_SECONDS = 5.0


@dataclass(frozen=True)
class MoveNote:
    """A move the operator made, until the monitor's status records it."""

    source: HandlerPod
    destination: HandlerPod
    reason: str
    ms: float
    # the source's report on it right after the move: the counts it reached there (a
    # drained handler exits soon after, and the next survey would not hear them)
    final: MonitorReport | None = None
    at: float = field(default_factory=time.monotonic)  # when it was done


@dataclass
class Operator:
    """What the operator keeps between handler calls (in Kopf's ``memo``)."""

    config: OperatorConfig
    orchestrator: Orchestrator
    # the handler pods, indexed in their namespace by an operator of its own (startup starts
    # it; one never started knows no pod)
    pods: PodWatch = field(default_factory=lambda: PodWatch(""))
    moving: threading.Lock = field(default_factory=threading.Lock)  # one move at a time
    surveying: threading.Lock = field(default_factory=threading.Lock)
    surveyed_at: float = float("-inf")
    placed_at: float = float("-inf")  # the last placement round
    reports: dict[HandlerPod, dict[str, MonitorReport]] = field(default_factory=dict)
    silent: set[HandlerPod] = field(default_factory=set)
    notes: dict[str, MoveNote] = field(default_factory=dict)  # monitor -> its last move
    # instance -> the document last given to its handlers (a retry, or a spec edit that
    # leaves an instance's document as it was, does not restart it)
    defined: dict[str, str] = field(default_factory=dict)
    # the last survey by monitor (name -> pod -> report), and which pods it asked
    index: dict[str, dict[HandlerPod, MonitorReport]] = field(default_factory=dict)
    pods_seen: tuple[frozenset[HandlerPod], frozenset[HandlerPod]] = (frozenset(), frozenset())
    # a fleet's instance -> what its robot's entry was made from, and the entry: an
    # instance whose reports did not change keeps its entry (no work per idle instance)
    entries: dict[str, tuple[Any, dict[str, Any]]] = field(default_factory=dict)
    # the budgeted tier's handler pods' CPU budgets (None: no tier's is set)
    levers: Levers | None = None
    # the survey's client of each handler pod (used under ``surveying`` only): each
    # keeps the last listing and is sent only what changed since (an idle fleet's
    # instances are not read again each round)
    surveyors: dict[HandlerPod, HandlerClient] = field(default_factory=dict)

    def client(self, pod: HandlerPod) -> HandlerClient:
        return HandlerClient(self.config.url(pod.address), self.config.token, self.config.tls)

    def target(self, pod: HandlerPod) -> Target:
        """The pod as the placement rounds poll it."""
        return Target(pod.tier or "", self.config.url(pod.address), pod.robot)

    def seen(self, pods: Sequence[HandlerPod]) -> dict[HandlerPod, HandlerReport]:
        """The pods' loads as the placement rounds last read them (a pod not read yet: none)."""
        found = ((p, self.orchestrator.seen.get(self.target(p))) for p in pods)
        return {p: report for p, report in found if report is not None}


def _operator(memo: kopf.Memo) -> Operator:
    op = memo.get("edgerv")
    if not isinstance(op, Operator):
        raise kopf.TemporaryError("the operator is starting", delay=2)
    return op


CONFIG = "config"  # the memo's key of the settings edgerv-operator read


@kopf.on.startup()
def startup(settings: kopf.OperatorSettings, memo: kopf.Memo, **_: Any) -> None:
    """The settings ``edgerv-operator`` read (in the memo), or, started by ``kopf run``,
    read now; the pods' watch started, the :class:`Operator` in the memo."""
    config = memo.get(CONFIG)
    if not isinstance(config, OperatorConfig):
        try:
            config = OperatorConfig.from_env()
        except ConfigError as exc:
            raise kopf.PermanentError(f"edgerv operator: {exc}") from None
    settings.persistence.finalizer = FINALIZER
    # Neither namespaces nor CRDs observed (Kopf's strict mode): the namespaces are the
    # ones named, the Monitor CRD the one served at startup; no cluster-wide read of
    # either (helm/README.md, "RBAC").
    settings.scanning.disabled = True
    # Kopf's own "handler succeeded" lines stay in the log; Events are the ones this
    # operator posts (kopf.event), and Kopf's warnings and errors.
    settings.posting.level = logging.WARNING
    policy = Orchestrator([], config.policy, config.token, starts=False, tls=config.tls)
    pods = PodWatch(config.namespace, config.selector_labels)
    pods.start()
    if not pods.wait_listed():
        log.warning("no pod listed in %s yet: going on with no handler pod known", config.namespace)
    op = memo["edgerv"] = Operator(config, policy, pods)
    if config.budget is not None:
        op.levers = Levers(config.budget_tier, config.budget, config.namespace, core_api, op.target)


STOP_SECONDS = 60.0  # how long a stopping operator waits for its move in progress


@kopf.on.cleanup()
def stopping(memo: kopf.Memo, **_: Any) -> None:
    """Graceful shutdown: wait for a move in progress to end (it holds the moves' lock),
    keep the lock so no other starts, and settle what a move left held (the handlers
    asked afresh): the operator leaves no handoff unsettled. The chart's grace period
    (75 s) covers the wait; past it, the next operator settles what is left."""
    op = memo.get("edgerv")
    if not isinstance(op, Operator):
        return
    try:
        _stop_moving(op)
    finally:
        op.pods.stop()


def _stop_moving(op: Operator) -> None:
    if not op.moving.acquire(timeout=STOP_SECONDS):
        log.warning("stopping with a move still running after %.0f s", STOP_SECONDS)
        return
    for pod in list(op.reports):
        try:
            op.reports[pod] = {m["name"]: m for m in op.client(pod).monitors(timeout=5.0)}
        except ApiError as exc:
            log.warning("stopping: %s did not list its monitors: %s", pod.node, exc)
    settle_orphans(op, list(op.reports))
    log.info("stopped: no move of this operator in progress")


login = kopf.on.login()(pods_login)  # in a pod: its service account; else $KUBECONFIG


@kopf.on.probe(id="handlers")
def probe(memo: kopf.Memo, **_: Any) -> int:
    """For the liveness endpoint: the operator is up (how many handlers it last saw), and
    so is its watch of the handler pods (else the probe fails: the pod restarts)."""
    op = memo.get("edgerv")
    if isinstance(op, Operator) and not op.pods.alive:
        raise kopf.PermanentError("the watch of the handler pods stopped")
    return len(op.reports) if isinstance(op, Operator) else 0


# -- what the cluster has: handler pods (edgerv_operator.pods) and the nodes' tiers ----------


@kopf.index("", "v1", "nodes")
def node_labels(name: str, labels: kopf.Labels, **_: Any) -> dict[str, dict[str, str]]:
    """Each node's labels (its tier is the one the chart's ``handler.tierLabel`` names)."""
    return {name: dict(labels)}


@dataclass(frozen=True)
class Handlers:
    """The handler pods of the cluster, as the index shows them now."""

    ready: list[HandlerPod]  # they run monitors and receive them
    leaving: list[HandlerPod]  # going away: what runs there moves off
    unready: list[HandlerPod]  # running, not Ready: asked, given nothing

    @property
    def every(self) -> list[HandlerPod]:
        return self.ready + self.leaving + self.unready

    def hosting(self, robot: str | None) -> Handlers:
        """Those that may run an instance of ``robot``: its robot's and the shared ones."""

        def mine(pods: list[HandlerPod]) -> list[HandlerPod]:
            return [p for p in pods if may_host(robot, p.robot)]

        return Handlers(mine(self.ready), mine(self.leaving), mine(self.unready))


_REFUSED_SAID: set[tuple[str, str]] = set()  # (node, label value) warned about once


def cluster_fleet(cfg: OperatorConfig, nodes: kopf.Index[str, dict[str, str]]) -> Fleet:
    """The cluster's robots, from its nodes' labels (the chart's ``fleet.robotLabel``);
    a node labelled with no valid robot name is said once in the log."""
    labels = {}
    for node in list(nodes):
        try:
            labels[node] = next(iter(nodes[node]), {})
        except KeyError:  # gone meanwhile
            continue
    fleet = fleet_of(labels, cfg.robot_label)
    for node, value in fleet.refused.items():
        if (node, value) not in _REFUSED_SAID:
            _REFUSED_SAID.add((node, value))
            log.warning(
                "node %s: %s=%r names no robot (a lower-case letter, then letters, digits "
                "and '-', at most 63): its handler runs nothing",
                node,
                cfg.robot_label,
                value,
            )
    return fleet


def pod_facts(pods: Mapping[str, Any]) -> list[PodFacts]:
    """What the pods index holds now. Its operator's thread updates it meanwhile: the keys
    and each key's values are copied whole (one C call each, under the GIL)."""
    facts = []
    for key in list(pods):
        try:
            facts += list(pods[key])
        except KeyError:  # gone meanwhile
            continue
    return facts


def cluster_handlers(
    cfg: OperatorConfig, pods: Mapping[str, Any], nodes: kopf.Index[str, dict[str, str]]
) -> Handlers:
    found = Handlers([], [], [])
    fleet = cluster_fleet(cfg, nodes)
    for p in pod_facts(pods):
        if p.namespace != cfg.namespace:
            continue
        labels = next(iter(nodes.get(p.node, [])), {})
        tier = labels.get(cfg.tier_label)
        h = HandlerPod(
            p.node, tier, f"{p.host_ip}:{cfg.port}", p.name, p.incarnation, fleet.robot_of(p.node)
        )
        # a node whose robot label names no robot serves no one: asked, given nothing; nor
        # does a pod whose node is gone (`kubectl delete node`: its pods run on until the
        # pod garbage collector deletes them), which would otherwise read as a shared node
        ready = p.ready and p.node not in fleet.refused and p.node in nodes
        (found.leaving if p.leaving else found.ready if ready else found.unready).append(h)
    return found


# -- the survey, and tending the cluster (drains, placement rounds) ------------------------


def survey_and_tend(op: Operator, handlers: Handlers) -> None:
    """At most once per STATUS_SECONDS / 2 (the first status timer due does it): every
    handler's monitors in one call each, then drains and a placement round."""
    if time.monotonic() - op.surveyed_at < STATUS_SECONDS / 2:
        return
    if not op.surveying.acquire(blocking=False):
        return  # another timer is at it: use the last survey
    try:
        started = time.monotonic()  # a move noted after this is not in these reports
        reports: dict[HandlerPod, dict[str, MonitorReport]] = {}
        silent: set[HandlerPod] = set()
        op.surveyors = {p: op.surveyors.get(p) or op.client(p) for p in handlers.every}
        for pod in handlers.every:
            try:
                listing = op.surveyors[pod].monitors(timeout=5.0)
                reports[pod] = {m["name"]: m for m in listing}
            except ApiError as exc:
                silent.add(pod)
                log.warning("handler %s on %s: no survey: %s", pod.pod, pod.node, exc)
        op.reports, op.silent, op.surveyed_at = reports, silent, started
        op.index = {}  # each monitor's reports, by pod: a fleet's refresh reads them so
        for pod, found in reports.items():
            for n, r in found.items():
                op.index.setdefault(n, {})[pod] = r
        op.pods_seen = (frozenset(reports), frozenset(silent))
        tend(op, handlers)
    finally:
        op.surveying.release()


def tend(op: Operator, handlers: Handlers) -> None:
    """Drains first (a pod going away hands its active monitors over), then one round
    of the placement policy over the ready handlers."""
    if not op.moving.acquire(blocking=False):
        return  # a tier edit is moving a monitor: next time
    try:
        settle_orphans(op, handlers.every)
        ready = handlers.ready
        for pod in handlers.leaving:
            active = {
                n: r["placement"].get("robot")
                for n, r in op.reports.get(pod, {}).items()
                if r.get("active")
            }
            for target, names in drained(pod, active, ready, op.config.tiers):
                _move(op, pod, target, names, f"pod {pod.pod} is going away")
        every = op.config.placement_seconds
        if every > 0 and time.monotonic() - op.placed_at >= every:
            op.placed_at = time.monotonic()
            by_url = {op.config.url(h.address): h for h in ready}
            op.orchestrator.set_targets(
                [op.target(h) for h in by_url.values() if h.tier in op.config.tiers]
            )
            if op.levers is not None:
                op.orchestrator.set_levers(op.levers.of(list(by_url.values())))
            for record in op.orchestrator.round():
                log.info("placement: %s", record)
                src = by_url.get(str(record.get("from") or ""))
                dst = by_url.get(str(record.get("to") or ""))
                if record.get("ok") and src and dst:
                    for name in record["monitors"]:
                        op.notes[name] = MoveNote(src, dst, str(record["reason"]), record["ms"])
    finally:
        op.moving.release()


HELD = ("sending", "released")  # a sender's handoff steps: it may hold the only copy


def settle_orphans(op: Operator, pods: Sequence[HandlerPod]) -> None:
    """Settle the handoffs that no move of this operator drives (the caller holds
    ``op.moving``, which every move of its holds throughout): the operator restarted in
    the middle of one, or a move of its failed without knowing whether the receiver
    adopted. As ``edgerv migrate`` settles them: a monitor the receiver adopted commits
    there, any other resumes on its sender; never two active copies."""
    for pod in pods:
        held = [name for name, r in op.reports.get(pod, {}).items() if r["handoff"] in HELD]
        if not held:
            continue
        try:
            _settle(op, pod, held)
        except ApiError as exc:
            log.warning("settling %s on %s: %s", ", ".join(held), pod.node, exc)


def _settle(op: Operator, pod: HandlerPod, held: list[str]) -> None:
    where = settle(op.client(pod), held, time.monotonic() + 30.0)
    moved = {n for names in where.values() for n in names}
    log.info(
        "settled a handoff no one drove: %s",
        "; ".join(f"{n} {'moved' if n in moved else 'resumed on ' + pod.node}" for n in held),
    )


def settle_held(op: Operator, pods: Sequence[HandlerPod], hname: str) -> None:
    """Before a spec is applied (the caller holds ``op.moving``): settle a handoff that
    holds this monitor, asked afresh of each handler (a restarted operator has no survey
    yet). A definition given to a handler in the middle of a handoff would restart the
    monitor there and lose the move; handlers refuse it (409) until it is settled."""
    for pod in pods:
        report = op.client(pod).monitor(hname, timeout=5.0)
        if report is not None and report["handoff"] in HELD:
            _settle(op, pod, [hname])


def _move(
    op: Operator, source: HandlerPod, target: HandlerPod, names: Sequence[str], reason: str
) -> bool:
    """Move ``names`` by the handoff (the caller holds ``op.moving``); note each move."""
    started = time.monotonic()
    try:
        migrate(op.client(source), op.client(target), list(names), timeout=30.0)
    except ApiError as exc:
        log.warning("moving %s from %s to %s: %s", ", ".join(names), source.node, target.node, exc)
        return False
    ms = (time.monotonic() - started) * 1000
    try:
        final = {m["name"]: m for m in op.client(source).monitors(timeout=5.0)}
    except ApiError as exc:
        log.warning("after moving from %s: no final counts: %s", source.node, exc)
        final = {}
    for name in names:
        op.notes[name] = MoveNote(source, target, reason, ms, final.get(name))
    log.info("moved %s from %s to %s (%s)", ", ".join(names), source.node, target.node, reason)
    return True


def _runs(report: MonitorReport | None) -> bool:
    return report is not None and report["active"]


def survey_of(op: Operator, hname: str) -> Survey:
    """The last survey's reports on one monitor (from its index: the pods that define
    it, not every pod that answered)."""
    return Survey(op.index.get(hname) or {}, list(op.silent), op.pods_seen[0])


# -- defining and placing a monitor ---------------------------------------------------------


def _now() -> str:
    return datetime.datetime.now(datetime.UTC).strftime("%Y-%m-%dT%H:%M:%SZ")


def _post(body: kopf.Body, events: Sequence[Event]) -> None:
    for e in events:
        kopf.event(body, type=e.type, reason=e.reason, message=e.message)


def _transient(exc: ApiError) -> kopf.TemporaryError:
    if isinstance(exc, Unauthorized):
        return kopf.TemporaryError(
            f"{exc}: the handlers refuse the operator's token (it differs from theirs: a "
            "rotated Secret reaches each pod within the kubelet's sync period, about a "
            "minute; with EDGERV_TOKEN instead of EDGERV_TOKEN_FILE, restart the operator)",
            delay=30,
        )
    return kopf.TemporaryError(str(exc), delay=10)


def place(
    op: Operator,
    handlers: Handlers,
    instance: Instance,
    spec: Mapping[str, Any],
    redefine: bool,
) -> None:
    """Define the instance on every ready handler of ``handlers`` (those that may run it),
    running on one.

    ``redefine``: give the definition to every handler (a new or changed spec: that
    restarts it, unless only its placement changed). Otherwise (the operator or a
    handler restarted) only handlers lacking it get it; what runs keeps its state."""
    hname, document, ready = instance.hname, instance.document, handlers.ready
    if not ready:
        whose = f" on robot {instance.robot}'s nodes or a shared one" if instance.robot else ""
        raise kopf.TemporaryError(
            f"no edgerv handler is ready in {op.config.namespace}{whose}", delay=10
        )
    elsewhere = [
        p for p in handlers.leaving + handlers.unready if _runs(op.reports.get(p, {}).get(hname))
    ]
    if elsewhere:  # never a second active copy: it moves off (leaving) or comes back
        raise kopf.TemporaryError(
            f"it runs on {elsewhere[0].pod}, which is going away or not ready: waiting", delay=10
        )
    try:
        reports = {p: op.client(p).monitor(hname, timeout=5.0) for p in ready}
        running = [p for p, r in reports.items() if r and r.get("active")]
        placement = placement_of(spec)
        policy = op.orchestrator.config
        target = running[0] if running else choose(ready, placement, policy, op.seen(ready))
        if target is None:
            home = placement.tier if placement.tier in op.config.tiers else op.config.tiers[0]
            budget = placement.max_latency_ms
            allowed = f" within {budget:g} ms (placement.maxLatencyMs)" if budget else ""
            raise kopf.TemporaryError(
                f"no handler of tier {home} or above{allowed} is ready (tiers, lowest first: "
                f"{','.join(op.config.tiers)}): it starts when one is",
                delay=15,
            )
        for p in sorted(ready, key=lambda p: p == target):  # idle everywhere first, then run
            if redefine or reports[p] is None:
                op.client(p).define(hname, document, active=p == target, timeout=30.0)
            elif p == target and not _runs(reports[p]):
                op.client(p).activate(hname, timeout=30.0)
    except Invalid as exc:  # the handler refuses the definition: fix the resource
        raise kopf.PermanentError(str(exc)) from None
    except ApiError as exc:
        raise _transient(exc) from None
    if redefine:
        op.defined[hname] = document
    op.surveyed_at = float("-inf")  # the next status refresh surveys afresh


MAX_NAME = 253  # a monitor's name on the handlers: a Kubernetes object name


@dataclass(frozen=True)
class Instance:
    """One of a Monitor's instances: its name on the handlers, its robot (None: the
    Monitor of a cluster without robots, run once as written) and its document."""

    hname: str
    robot: str | None
    document: str


def instances(name: str, namespace: str, spec: Mapping[str, Any], fleet: Fleet) -> list[Instance]:
    """A Monitor's instances: one per robot its ``spec.robots`` selects when the cluster
    has robots (none when it selects none), else one. A spec that cannot run: a
    PermanentError saying why, by field path."""
    parsed, errors = read(monitor_document(namespace, name, spec))
    if errors or parsed is None:
        raise kopf.PermanentError("; ".join(errors) or "the spec cannot be read")
    if not fleet.robots:
        return [Instance(handler_name(namespace, name), None, _text(namespace, name, spec, None))]
    key = json.dumps(spec, sort_keys=True)  # (each refresh asks again: made once a spec)
    found = [_instance(namespace, name, key, robot) for robot in fleet.selected(parsed.robots)]
    for inst in found:
        if len(inst.hname) > MAX_NAME:
            raise kopf.PermanentError(
                f"metadata.name: the instance for robot {inst.robot} would be named "
                f"{inst.hname[:40]}... ({len(inst.hname)} characters, at most {MAX_NAME}): "
                "shorten the Monitor's name"
            )
    return found


def _text(namespace: str, name: str, spec: Mapping[str, Any], robot: str | None) -> str:
    return document_text(instance_document(namespace, name, spec, robot))


@functools.lru_cache(maxsize=65536)
def _instance(namespace: str, name: str, spec: str, robot: str) -> Instance:
    """A robot's instance of the Monitor whose spec is ``spec`` (JSON, keys sorted)."""
    doc = instance_document(namespace, name, json.loads(spec), robot)
    return Instance(str(doc["metadata"]["name"]), robot, document_text(doc))


def _apply(
    name: str,
    namespace: str,
    spec: Mapping[str, Any],
    status: Mapping[str, Any],
    meta: kopf.Meta,
    body: kopf.Body,
    patch: kopf.Patch,
    memo: kopf.Memo,
    node_labels: kopf.Index[str, dict[str, str]],
    redefine: bool,
    old: Mapping[str, Any] | None = None,
) -> None:
    op = _operator(memo)
    generation = int(meta.get("generation") or 0)
    handlers = cluster_handlers(op.config, op.pods.index, node_labels)
    what = change(old, spec) if old is not None else ("redefine" if redefine else "none")
    waiting: list[str] = []  # instances that wait for a handler (the others are placed)
    try:  # refused here or by the handlers: the spec is wrong, until it changes
        found = instances(name, namespace, spec, cluster_fleet(op.config, node_labels))
        with op.moving:  # no move runs meanwhile: none is undone by a definition
            for inst in found:
                mine = handlers.hosting(inst.robot)
                settle_held(op, mine.ready, inst.hname)
                anew = what in ("redefine", "placement", "move") and (
                    op.defined.get(inst.hname) != inst.document
                )
                try:
                    place(op, mine, inst, spec, redefine=anew)
                    if what == "move":  # placement in place (above), then the handoff
                        _move_to_tier(op, mine.ready, inst.hname, spec)
                except kopf.TemporaryError as exc:
                    if len(found) == 1:
                        raise
                    waiting.append(f"robot {inst.robot}: {exc}")
    except ApiError as exc:  # settling: the handler did not answer
        raise _transient(exc) from None
    except kopf.PermanentError as exc:
        new, events = invalid(status, str(exc), generation, _now())
        new.pop("kopf", None)
        patch.status.update(new)
        _post(body, events)
        raise
    patch.status["observedGeneration"] = generation
    if what == "redefine" and old is not None:
        kopf.event(
            body,
            type="Normal",
            reason="Redefined",
            message="the spec changed: the monitor restarted with it (its state afresh)",
        )
    if waiting:  # the placed ones are not given their definition again: no restart
        raise kopf.TemporaryError("; ".join(waiting), delay=10)


def _move_to_tier(
    op: Operator, ready: list[HandlerPod], hname: str, spec: Mapping[str, Any]
) -> None:
    """A tier edit: move the running monitor to a handler of its new tier by the handoff
    (``ready``: the handlers that may run it)."""
    tier = tier_of(spec)
    runner = None
    for p in ready:
        report = op.client(p).monitor(hname, timeout=5.0)
        if report and report.get("active"):
            runner = p
    if runner is None or runner.tier == tier or tier is None:
        return  # not running yet (it starts on its tier), or there already
    target = destination(ready, tier, op.config.tiers)
    if target is None:
        raise kopf.TemporaryError(f"no handler of tier {tier} is ready: the move waits", delay=15)
    if not _move(op, runner, target, [hname], f"spec.placement.tier is {tier}"):
        raise kopf.TemporaryError(f"the move to {target.node} did not happen: retrying", delay=10)


@kopf.on.create(*MONITORS)
def created(
    name: str, namespace: str | None, spec: kopf.Spec, status: kopf.Status, **kw: Any
) -> None:
    _apply(name, namespace or "", dict(spec), dict(status), redefine=True, **_kopf(kw))


@kopf.on.update(*MONITORS, field="spec")
def updated(
    name: str,
    namespace: str | None,
    old: Any,
    new: Any,
    status: kopf.Status,
    **kw: Any,
) -> None:
    _apply(
        name, namespace or "", dict(new or {}), dict(status), redefine=True, old=dict(old or {}),
        **_kopf(kw),
    )  # fmt: skip


@kopf.on.resume(*MONITORS)
def resumed(
    name: str, namespace: str | None, spec: kopf.Spec, status: kopf.Status, **kw: Any
) -> None:
    """The operator restarted: what runs goes on running (its state intact)."""
    _apply(name, namespace or "", dict(spec), dict(status), redefine=False, **_kopf(kw))


def _kopf(kw: Mapping[str, Any]) -> dict[str, Any]:
    keys = ("meta", "body", "patch", "memo", "node_labels")
    return {k: kw[k] for k in keys}


def ours(op: Operator, base: str) -> dict[str, str | None]:
    """The instances of the Monitor named ``base`` on the handlers that the last survey
    found (name -> robot): ``base`` itself (no robot), and ``base.ROBOT`` labelled ROBOT."""
    found: dict[str, str | None] = {}
    for reports in op.reports.values():
        for n, r in reports.items():
            robot = r["placement"].get("robot")
            if (n == base and robot is None) or (robot is not None and n == f"{base}.{robot}"):
                found[n] = robot
    return found


def _remove(op: Operator, pods: Sequence[HandlerPod], names: Sequence[str]) -> list[str]:
    """Remove ``names`` from every pod; what did not answer, said."""
    unanswered = []
    for pod in pods:
        for hname in names:
            try:
                op.client(pod).delete(hname, timeout=10.0)
            except NotFound:
                pass
            except ApiError as exc:
                unanswered.append(f"{hname} on {pod.pod} ({pod.node}): {exc}")
        for hname in names:
            op.notes.pop(hname, None)
            op.defined.pop(hname, None)
            op.entries.pop(hname, None)
    return unanswered


@kopf.on.delete(*MONITORS)
def deleted(
    name: str,
    namespace: str | None,
    spec: kopf.Spec,
    memo: kopf.Memo,
    **kw: Any,
) -> None:
    """Remove each instance from every handler pod there is; one that does not answer is
    asked again until it does or its pod is gone (the finalizer holds the Monitor
    meanwhile)."""
    op = _operator(memo)
    handlers = cluster_handlers(op.config, op.pods.index, kw["node_labels"])
    base = handler_name(namespace or "", name)
    names = set(ours(op, base)) | {base}
    try:
        fleet = cluster_fleet(op.config, kw["node_labels"])
        names |= {i.hname for i in instances(name, namespace or "", dict(spec), fleet)}
    except kopf.PermanentError:
        pass  # a spec that never ran: its name alone
    unanswered = _remove(op, handlers.every, sorted(names))
    if unanswered:
        raise kopf.TemporaryError(
            "not yet removed from " + "; ".join(unanswered) + " (retrying until it answers "
            "or its pod is gone)",
            delay=10,
        )


@kopf.timer(*MONITORS, interval=STATUS_SECONDS, initial_delay=STATUS_SECONDS)
def refresh(
    name: str,
    namespace: str | None,
    spec: kopf.Spec,
    status: kopf.Status,
    meta: kopf.Meta,
    body: kopf.Body,
    patch: kopf.Patch,
    memo: kopf.Memo,
    **kw: Any,
) -> None:
    """Refresh the status from the survey; post the Events it calls for; remove the
    instances of robots no longer selected (or gone); give the definition again to
    handlers that lost it (never during a handoff: a new definition would restart the
    monitor and undo it)."""
    generation = int(meta.get("generation") or 0)
    if status.get("phase") == "Error" and status.get("observedGeneration") == generation:
        return  # until the spec changes
    op = _operator(memo)
    handlers = cluster_handlers(op.config, op.pods.index, kw["node_labels"])
    survey_and_tend(op, handlers)
    namespace = namespace or ""
    fleet = cluster_fleet(op.config, kw["node_labels"])
    found = instances(name, namespace, dict(spec), fleet)
    if any(
        n is not None and n.at >= op.surveyed_at for n in (op.notes.get(i.hname) for i in found)
    ):
        op.surveyed_at = float("-inf")  # its reports predate a move: next time, afresh
        return
    base = handler_name(namespace, name)
    wanted = {i.hname for i in found}
    stale = [n for n in ours(op, base) if n not in wanted and not _in_handoff(op, n)]
    if stale and op.moving.acquire(blocking=False):  # (a move runs: next time)
        try:  # a robot gone, or no longer selected: its instance goes
            _remove(op, handlers.every, stale)
            log.info("removed %s: no robot of %s/%s runs it now", ", ".join(stale), namespace, name)
        finally:
            op.moving.release()
    if fleet.robots:
        new, events = _fleet_status(op, dict(status), found, generation, fleet)
    else:
        new, events = _instance_status(op, dict(status), found[0].hname, generation)
        for key in FLEET_FIELDS:  # from when the cluster had robots
            if key in status:
                new[key] = None
    new.pop("kopf", None)  # Kopf's own field: its progress is not ours to write
    patch.status.update(changed(status, new))
    _post(body, events)
    waiting = []
    for inst in found:
        try:
            _replace_lost(op, handlers.hosting(inst.robot), inst, dict(spec))
        except kopf.TemporaryError as exc:
            if len(found) == 1:
                raise
            waiting.append(f"robot {inst.robot}: {exc}")
    if waiting:
        raise kopf.TemporaryError("; ".join(waiting), delay=10)


def changed(status: Mapping[str, Any], new: Mapping[str, Any]) -> dict[str, Any]:
    """The merge patch from ``status`` to ``new``: the fields whose value differs, and of
    ``robots`` the robots whose entry does (a fleet's status is large: most refreshes of
    an idle fleet patch nothing)."""
    out: dict[str, Any] = {}
    for key, value in new.items():
        was = status.get(key)
        if key == "robots" and isinstance(value, Mapping) and isinstance(was, Mapping):
            robots = {r: e for r, e in value.items() if was.get(r) != e}
            if robots:
                out[key] = robots
        elif was != value or key not in status:
            out[key] = value
    return out


def _in_handoff(op: Operator, hname: str) -> bool:
    return any((r := reports.get(hname)) and r["handoff"] for reports in op.reports.values())


def _instance_status(
    op: Operator, previous: dict[str, Any], hname: str, generation: int
) -> tuple[dict[str, Any], list[Event]]:
    """The status of one instance (a Monitor's in a cluster without robots: its whole
    status; a robot's: its entry in ``status.robots``), its move noted, from the survey."""
    events: list[Event] = []
    note = op.notes.pop(hname, None)
    if note is not None:
        previous, events = moved(
            previous, note.source, note.destination, note.reason, _now(), note.ms
        )
    survey = survey_of(op, hname)
    if note is not None and note.final is not None:  # what it counted up to the move
        survey = Survey(
            {**survey.reports, note.source: note.final},
            [p for p in survey.silent if p != note.source],
            {*survey.pods(), note.source},
        )
    new, more = refreshed(previous, survey, generation, _now(), time.time())
    seen_before = ((previous.get("tally") or {}).get("seen") or {}).keys()
    for key in seen_before - new["tally"]["seen"].keys():
        new["tally"]["seen"][key] = None  # a merge patch removes it
    return new, events + more


def _fleet_status(
    op: Operator, previous: dict[str, Any], found: list[Instance], generation: int, fleet: Fleet
) -> tuple[dict[str, Any], list[Event]]:
    """A fleet's Monitor: each selected robot's entry, then the totals."""
    before = previous.get("robots") or {}
    robots: dict[str, dict[str, Any]] = {}
    events: list[Event] = []
    for inst in found:
        assert inst.robot is not None
        was = dict(before.get(inst.robot) or {})
        made_of = (generation, op.pods_seen, op.index.get(inst.hname))
        kept = op.entries.get(inst.hname)
        if (
            inst.hname not in op.notes
            and kept
            and kept[0] == made_of
            and kept[1] == was
            and not _event_owed(was)
        ):
            robots[inst.robot] = was  # its reports as before: its entry as before
            continue
        entry, more = _instance_status(op, was, inst.hname, generation)
        robots[inst.robot] = robot_refreshed(entry)
        op.entries[inst.hname] = (made_of, robots[inst.robot])
        events += [Event(e.type, e.reason, f"robot {inst.robot}: {e.message}") for e in more]
    return fleet_refreshed(previous, robots, sorted(fleet.robots), generation, _now(), events)


def _event_owed(entry: Mapping[str, Any]) -> bool:
    """Violations counted that no Violated Event has told yet (it waits out the minute
    between two: status.VIOLATION_EVENT_SECONDS), to be told by a refresh to come."""
    told = (entry.get("violationEvents") or {}).get("reported", 0)
    return int((entry.get("verdicts") or {}).get("violated", 0)) > int(told)


def _replace_lost(op: Operator, handlers: Handlers, inst: Instance, spec: dict[str, Any]) -> None:
    """Give the definition again to the handlers that lost it, and start it where it
    runs nowhere (never during a handoff)."""
    survey = survey_of(op, inst.hname)
    reports = survey.reports
    moving = any(r and r.get("handoff") for r in reports.values())
    lacking = any(survey.defines(p) is False for p in handlers.ready)
    if not moving and (lacking or not any(r and r.get("active") for r in reports.values())):
        place(op, handlers, inst, spec, redefine=False)
