"""The operator's settings: one validated object from the environment, errors that name
the variable."""

from __future__ import annotations

import os
from collections.abc import Mapping
from dataclasses import dataclass

DEFAULT_SELECTOR = "app.kubernetes.io/name=edgerv,app.kubernetes.io/component=handler"


class ConfigError(Exception):
    """A setting that cannot be used: which variable, and why."""


@dataclass(frozen=True)
class OperatorConfig:
    namespace: str  # where the handler pods run
    selector: str  # the handler pods' label selector
    port: int  # the handlers' control API port (host networking: on each node's address)
    token: str  # the handlers' EDGERV_TOKEN
    tiers: tuple[str, ...]  # lowest first: a monitor without placement.tier starts on the first
    placement_seconds: float = 5.0  # between rounds of the placement policy; 0: none

    @classmethod
    def from_env(cls, env: Mapping[str, str] | None = None) -> OperatorConfig:
        env = os.environ if env is None else env

        token = env.get("EDGERV_TOKEN", "")
        if not token:
            raise ConfigError(
                "EDGERV_TOKEN: not set: the operator calls the handlers' API with the "
                "handlers' token (the chart puts it in a Secret)"
            )
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
        return cls(
            namespace=namespace,
            selector=env.get("EDGERV_HANDLER_SELECTOR", DEFAULT_SELECTOR),
            port=int(text),
            token=token,
            tiers=tiers,
            placement_seconds=placement_seconds,
        )
