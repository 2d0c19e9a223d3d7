"""The operator's settings: the environment read once, into one frozen object, with errors
that name the variable. Nothing else in the operator reads the environment.

:meth:`OperatorConfig.from_env` is the operator's (``edgerv-operator`` reads it before Kopf
starts and hands it to the handlers in Kopf's ``memo``) and the self-test's;
:meth:`UninstallConfig.from_env` the uninstall hook's, which has no token.
"""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass, field

from edgerv.control.placement import PolicyConfig, tier_latencies
from edgerv.control.tls import ClientTls
from edgerv.control.token import Token, TokenFile
from edgerv.core.diagnostics import InputError
from edgerv.core.planner import BudgetConfig
from edgerv.core.robots import LABEL_KEY
from edgerv_operator.constants import (
    BUDGET_CEILING,
    BUDGET_FLOOR,
    BUDGET_HYSTERESIS,
    BUDGET_WAIT,
    HANDLER_PORT,
    HANDLER_SELECTOR,
    LIVENESS,
    PLACEMENT_SECONDS,
    ROBOT_LABEL,
    TIER_LABEL,
    TIERS,
)

VARIABLES = (  # every variable the operator, its self-test and its uninstall hook read
    "EDGERV_NAMESPACE",
    "POD_NAMESPACE",
    "EDGERV_TOKEN",
    "EDGERV_TOKEN_FILE",
    "EDGERV_TLS_CA_FILE",
    "EDGERV_TLS_SERVER_NAME",
    "EDGERV_PLAIN_HTTP",
    "EDGERV_HANDLER_PORT",
    "EDGERV_HANDLER_SELECTOR",
    "EDGERV_TIERS",
    "EDGERV_TIER_LATENCY",
    "EDGERV_TIER_LABEL",
    "EDGERV_ROBOT_LABEL",
    "EDGERV_PLACEMENT_SECONDS",
    "EDGERV_WATCH_NAMESPACES",
    "EDGERV_PEERING",
    "EDGERV_LIVENESS",
    "EDGERV_OPERATOR_DEPLOYMENT",
    "EDGERV_BUDGET_TIER",
    "EDGERV_BUDGET_FLOOR",
    "EDGERV_BUDGET_CEILING",
    "EDGERV_BUDGET_HYSTERESIS",
    "EDGERV_BUDGET_WAIT",
)


class ConfigError(Exception):
    """A setting that cannot be used: which variable, and why."""


def parse_selector(text: str) -> dict[str, str] | None:
    """``key=value,key=value`` as a dict; None when it is not of that form."""
    labels = {}
    for part in text.split(","):
        key, eq, value = part.strip().partition("=")
        if not eq or not key.strip() or "!" in key or "=" in value:
            return None
        labels[key.strip()] = value.strip()
    return labels or None


def _label(env: Mapping[str, str], variable: str, default: str) -> str:
    """A node label key the operator reads (EDGERV_TIER_LABEL, EDGERV_ROBOT_LABEL)."""
    key = env.get(variable, default)
    if not LABEL_KEY.match(key):
        raise ConfigError(f"{variable}: '{key}' is not a label key (e.g. {default})")
    return key


def _environment(env: Mapping[str, str] | None) -> Mapping[str, str]:
    """``env``, or the process's environment (the one place the operator reads it)."""
    return os.environ if env is None else env


def _token(env: Mapping[str, str]) -> Token:
    """EDGERV_TOKEN_FILE (read again when it changes: a rotated Secret mounted as a
    volume), else EDGERV_TOKEN."""
    path = env.get("EDGERV_TOKEN_FILE", "")
    if path:
        try:
            return TokenFile(path)
        except OSError as exc:
            raise ConfigError(f"EDGERV_TOKEN_FILE: cannot read '{path}': {exc.strerror}") from None
        except (ValueError, UnicodeDecodeError):
            raise ConfigError(f"EDGERV_TOKEN_FILE: '{path}' is empty or not text") from None
    token = env.get("EDGERV_TOKEN", "")
    if not token:
        raise ConfigError(
            "EDGERV_TOKEN: not set (nor EDGERV_TOKEN_FILE): the operator calls the handlers' "
            "API with the handlers' token (the chart mounts it from a Secret)"
        )
    return token


def _tls(env: Mapping[str, str]) -> ClientTls | None:
    """EDGERV_TLS_CA_FILE (and EDGERV_TLS_SERVER_NAME): the handlers serve HTTPS; plain
    HTTP only when EDGERV_PLAIN_HTTP=true says so."""
    ca_file = env.get("EDGERV_TLS_CA_FILE", "")
    plain = env.get("EDGERV_PLAIN_HTTP", "").strip().lower() or "false"
    if plain not in ("true", "false"):
        raise ConfigError(f"EDGERV_PLAIN_HTTP: '{plain}' is not true or false")
    if plain == "true":
        if ca_file:
            raise ConfigError("EDGERV_PLAIN_HTTP: true, and EDGERV_TLS_CA_FILE is set: choose one")
        return None
    if not ca_file:
        raise ConfigError(
            "EDGERV_TLS_CA_FILE: not set: the CA that signed the handlers' certificates "
            "(the chart mounts it; EDGERV_PLAIN_HTTP=true calls them over plain HTTP)"
        )
    try:
        return ClientTls(ca_file, env.get("EDGERV_TLS_SERVER_NAME") or None)
    except InputError as exc:
        raise ConfigError(f"EDGERV_TLS_CA_FILE: {exc.diagnostics[0].message}") from None


def _namespace(env: Mapping[str, str]) -> str:
    namespace = env.get("EDGERV_NAMESPACE") or env.get("POD_NAMESPACE") or ""
    if not namespace:
        raise ConfigError("EDGERV_NAMESPACE: not set: the namespace of the handler pods")
    return namespace


def _watched(env: Mapping[str, str]) -> tuple[str, ...]:
    """EDGERV_WATCH_NAMESPACES: comma-separated, each once; empty: every namespace."""
    watched = (n.strip() for n in env.get("EDGERV_WATCH_NAMESPACES", "").split(","))
    return tuple(n for n in dict.fromkeys(watched) if n)


def _tiers(env: Mapping[str, str]) -> tuple[tuple[str, ...], dict[str, float]]:
    """EDGERV_TIERS, lowest first, and EDGERV_TIER_LATENCY (``TIER=MS,...``: each tier's
    latency from the robot, for ``placement.maxLatencyMs``; a tier not named: 0)."""
    given = env.get("EDGERV_TIERS", ",".join(TIERS))
    tiers = tuple(t.strip() for t in given.split(","))
    if not all(tiers) or len(set(tiers)) != len(tiers):
        raise ConfigError(
            f"EDGERV_TIERS: '{given}' is not a list of distinct tier names, lowest first "
            "(e.g. edge,cloud)"
        )
    try:
        latency = tier_latencies(env.get("EDGERV_TIER_LATENCY", ""))
    except ValueError as exc:
        raise ConfigError(f"EDGERV_TIER_LATENCY: {exc}") from None
    strangers = sorted(set(latency) - set(tiers))
    if strangers:
        raise ConfigError(
            f"EDGERV_TIER_LATENCY: tier {', '.join(strangers)} is not one of EDGERV_TIERS "
            f"{','.join(tiers)}"
        )
    return tiers, latency


def _budget(env: Mapping[str, str], tiers: tuple[str, ...]) -> tuple[str, BudgetConfig | None]:
    """EDGERV_BUDGET_TIER (the tier whose handlers' CPU budget the planner sets; empty:
    none) and its bounds: EDGERV_BUDGET_FLOOR and _CEILING (cores), _HYSTERESIS (a share
    of the budget), _WAIT (seconds)."""
    tier = env.get("EDGERV_BUDGET_TIER", "").strip()
    if not tier:
        return "", None
    if tier not in tiers:
        raise ConfigError(
            f"EDGERV_BUDGET_TIER: '{tier}' is not one of EDGERV_TIERS {','.join(tiers)}"
        )
    numbers = {}
    for name, default in (
        ("FLOOR", BUDGET_FLOOR),
        ("CEILING", BUDGET_CEILING),
        ("HYSTERESIS", BUDGET_HYSTERESIS),
        ("WAIT", BUDGET_WAIT),
    ):
        text = env.get(f"EDGERV_BUDGET_{name}", f"{default:g}")
        try:
            numbers[name] = float(text)
        except ValueError:
            raise ConfigError(f"EDGERV_BUDGET_{name}: '{text}' is not a number") from None
    try:
        bounds = BudgetConfig(
            numbers["FLOOR"], numbers["CEILING"], numbers["HYSTERESIS"], numbers["WAIT"]
        )
    except ValueError as exc:
        raise ConfigError(
            f"EDGERV_BUDGET_FLOOR, _CEILING, _HYSTERESIS, _WAIT: {exc} (cores; a share; seconds)"
        ) from None
    return tier, bounds


@dataclass(frozen=True)
class OperatorConfig:
    namespace: str  # where the handler pods run
    selector: str  # the handler pods' label selector
    port: int  # the handlers' control API port (host networking: on each node's address)
    token: Token  # the handlers' token: EDGERV_TOKEN_FILE (followed), else EDGERV_TOKEN
    tiers: tuple[str, ...]  # lowest first: a monitor without placement.tier starts on the first
    placement_seconds: float = PLACEMENT_SECONDS  # between rounds of the placement policy; 0: none
    tier_label: str = TIER_LABEL  # the node label whose value is the node's tier
    robot_label: str = ROBOT_LABEL  # the node label whose value names the node's robot
    tls: ClientTls | None = None  # how the handlers' certificates are verified (None: HTTP)
    tier_latency_ms: Mapping[str, float] = field(default_factory=dict)  # from the robot
    watch_namespaces: tuple[str, ...] = ()  # the Monitors' namespaces (empty: every one)
    peering: str = ""  # the Kopf peering object replicas meet in ("": it runs alone)
    liveness: str = LIVENESS  # where it answers its liveness probe ("": nowhere)
    # the tier whose handlers' CPU budget the planner sets, by resizing their pods in
    # place ("": none), and the budget's bounds
    budget_tier: str = ""
    budget: BudgetConfig | None = None

    def url(self, address: str) -> str:
        """A handler's API at ``HOST:PORT``, over HTTPS unless plain HTTP was asked for."""
        return f"{'https' if self.tls is not None else 'http'}://{address}"

    @property
    def policy(self) -> PolicyConfig:
        """The placement policy's settings: the tiers and their latencies, else defaults."""
        return PolicyConfig(tiers=self.tiers, tier_latency_ms=dict(self.tier_latency_ms))

    @property
    def selector_labels(self) -> dict[str, str]:
        """The handler pods' labels, for the pod index (:mod:`edgerv_operator.pods`)."""
        return parse_selector(self.selector) or {}

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> OperatorConfig:
        env = _environment(env)
        token = _token(env)
        tls = _tls(env)
        namespace = _namespace(env)
        tiers, latency = _tiers(env)
        text = env.get("EDGERV_HANDLER_PORT", str(HANDLER_PORT))
        if not text.isdigit() or not 1 <= int(text) <= 65535:
            raise ConfigError(f"EDGERV_HANDLER_PORT: '{text}' is not a port number (1-65535)")
        every = env.get("EDGERV_PLACEMENT_SECONDS", f"{PLACEMENT_SECONDS:g}")
        try:
            placement_seconds = float(every)
        except ValueError:
            placement_seconds = -1.0
        if not 0 <= placement_seconds <= 3600:
            raise ConfigError(
                f"EDGERV_PLACEMENT_SECONDS: '{every}' is not a number of seconds from 0 "
                "(no placement rounds) to 3600"
            )
        selector = env.get("EDGERV_HANDLER_SELECTOR", HANDLER_SELECTOR)
        if parse_selector(selector) is None:
            raise ConfigError(
                f"EDGERV_HANDLER_SELECTOR: '{selector}' is not a list of key=value labels "
                "(e.g. app.kubernetes.io/component=handler)"
            )
        budget_tier, budget = _budget(env, tiers)
        tier_label, robot_label = (
            _label(env, "EDGERV_TIER_LABEL", TIER_LABEL),
            _label(env, "EDGERV_ROBOT_LABEL", ROBOT_LABEL),
        )
        if tier_label == robot_label:
            raise ConfigError(
                f"EDGERV_ROBOT_LABEL: '{robot_label}' is the tier label too: a node's robot "
                "and its tier are two labels"
            )
        return cls(
            namespace=namespace,
            selector=selector,
            port=int(text),
            token=token,
            tiers=tiers,
            placement_seconds=placement_seconds,
            tier_label=tier_label,
            robot_label=robot_label,
            tls=tls,
            tier_latency_ms=latency,
            watch_namespaces=_watched(env),
            peering=env.get("EDGERV_PEERING", ""),
            liveness=env.get("EDGERV_LIVENESS", LIVENESS),
            budget_tier=budget_tier,
            budget=budget,
        )


@dataclass(frozen=True)
class UninstallConfig:
    """What the uninstall hook (:mod:`edgerv_operator.uninstall`) needs: the release's
    namespace, the operator's Deployment ("": none in the cluster), the namespaces whose
    Monitors it watched (empty: every one)."""

    namespace: str
    deployment: str = ""
    watch_namespaces: tuple[str, ...] = ()

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> UninstallConfig:
        env = _environment(env)
        return cls(_namespace(env), env.get("EDGERV_OPERATOR_DEPLOYMENT", ""), _watched(env))
