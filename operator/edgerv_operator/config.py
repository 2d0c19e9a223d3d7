"""The operator's settings: one validated object from the environment, errors that name
the variable."""

from __future__ import annotations

import os
import re
from collections.abc import Mapping
from dataclasses import dataclass

from edgerv.control.tls import ClientTls
from edgerv.control.token import Token, TokenFile
from edgerv.core.diagnostics import InputError

DEFAULT_SELECTOR = "app.kubernetes.io/name=edgerv,app.kubernetes.io/component=handler"


class ConfigError(Exception):
    """A setting that cannot be used: which variable, and why."""


# a Kubernetes label key: an optional DNS-subdomain prefix and a name of up to 63 characters
_LABEL_KEY = re.compile(
    r"([a-z0-9]([-a-z0-9]*[a-z0-9])?(\.[a-z0-9]([-a-z0-9]*[a-z0-9])?)*/)?"
    r"[A-Za-z0-9]([-A-Za-z0-9_.]{0,61}[A-Za-z0-9])?"
)


def parse_selector(text: str) -> dict[str, str] | None:
    """``key=value,key=value`` as a dict; None when it is not of that form."""
    labels = {}
    for part in text.split(","):
        key, eq, value = part.strip().partition("=")
        if not eq or not key.strip() or "!" in key or "=" in value:
            return None
        labels[key.strip()] = value.strip()
    return labels or None


def selector_labels(env: Mapping[str, str] | None = None) -> dict[str, str]:
    """The handler pods' labels, for the pod index (read when the handlers module is
    imported; a bad value falls back to the default, and startup refuses it)."""
    env = os.environ if env is None else env
    given = parse_selector(env.get("EDGERV_HANDLER_SELECTOR", DEFAULT_SELECTOR))
    return given or parse_selector(DEFAULT_SELECTOR) or {}


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


@dataclass(frozen=True)
class OperatorConfig:
    namespace: str  # where the handler pods run
    selector: str  # the handler pods' label selector
    port: int  # the handlers' control API port (host networking: on each node's address)
    token: Token  # the handlers' token: EDGERV_TOKEN_FILE (followed), else EDGERV_TOKEN
    tiers: tuple[str, ...]  # lowest first: a monitor without placement.tier starts on the first
    placement_seconds: float = 5.0  # between rounds of the placement policy; 0: none
    tier_label: str = "edgerv.io/tier"  # the node label whose value is the node's tier
    tls: ClientTls | None = None  # how the handlers' certificates are verified (None: HTTP)

    def url(self, address: str) -> str:
        """A handler's API at ``HOST:PORT``, over HTTPS unless plain HTTP was asked for."""
        return f"{'https' if self.tls is not None else 'http'}://{address}"

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> OperatorConfig:
        env = os.environ if env is None else env

        token = _token(env)
        tls = _tls(env)
        namespace = env.get("EDGERV_NAMESPACE") or env.get("POD_NAMESPACE") or ""
        if not namespace:
            raise ConfigError("EDGERV_NAMESPACE: not set: the namespace of the handler pods")
        tiers = tuple(t.strip() for t in env.get("EDGERV_TIERS", "edge,cloud").split(","))
        if not all(tiers) or len(set(tiers)) != len(tiers):
            raise ConfigError(
                f"EDGERV_TIERS: '{env.get('EDGERV_TIERS')}' is not a list of distinct tier "
                "names, lowest first (e.g. edge,cloud)"
            )
        text = env.get("EDGERV_HANDLER_PORT", "8470")
        if not text.isdigit() or not 1 <= int(text) <= 65535:
            raise ConfigError(f"EDGERV_HANDLER_PORT: '{text}' is not a port number (1-65535)")
        every = env.get("EDGERV_PLACEMENT_SECONDS", "5")
        try:
            placement_seconds = float(every)
        except ValueError:
            placement_seconds = -1.0
        if not 0 <= placement_seconds <= 3600:
            raise ConfigError(
                f"EDGERV_PLACEMENT_SECONDS: '{every}' is not a number of seconds from 0 "
                "(no placement rounds) to 3600"
            )
        selector = env.get("EDGERV_HANDLER_SELECTOR", DEFAULT_SELECTOR)
        if parse_selector(selector) is None:
            raise ConfigError(
                f"EDGERV_HANDLER_SELECTOR: '{selector}' is not a list of key=value labels "
                "(e.g. app.kubernetes.io/component=handler)"
            )
        tier_label = env.get("EDGERV_TIER_LABEL", "edgerv.io/tier")
        if not _LABEL_KEY.fullmatch(tier_label):
            raise ConfigError(
                f"EDGERV_TIER_LABEL: '{tier_label}' is not a label key (e.g. edgerv.io/tier)"
            )
        return cls(
            namespace=namespace,
            selector=selector,
            port=int(text),
            token=token,
            tiers=tiers,
            placement_seconds=placement_seconds,
            tier_label=tier_label,
            tls=tls,
        )
