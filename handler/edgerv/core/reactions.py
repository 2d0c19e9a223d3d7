"""What a monitor does when it is violated (``spec.onViolation``): publish a message, call
a service, or both. Pure: the definition and the check of its fields against the message
types; the handler's ROS layer does it (:mod:`edgerv.handler.ros.reactor`).

A message or request is written as a mapping of field values (nested mappings for nested
messages); every field it does not name keeps its default (zero, false, empty). The values
are checked here against the type's definition, as a signal's field path is, so a
Monitor that would publish a wrong field is refused where it is written, not at the
moment of the violation.
"""

from __future__ import annotations

from dataclasses import dataclass

from edgerv.core.msgtypes import ValueKind

Scalar = bool | int | float | str
# A message's fields as (dotted path, value) pairs, in the order written.
Fields = tuple[tuple[str, Scalar], ...]

DEFAULT_CALL_TIMEOUT = 1.0  # seconds: to find the service and for its answer


@dataclass(frozen=True)
class Publish:
    """Publish ``fields`` (a ``msg_type`` message, the rest default) on ``topic``."""

    topic: str
    msg_type: str
    fields: Fields = ()


@dataclass(frozen=True)
class Call:
    """Call ``service`` (of ``srv_type``, ``pkg/srv/Name``) with a request of ``fields``."""

    service: str
    srv_type: str
    fields: Fields = ()
    timeout: float = DEFAULT_CALL_TIMEOUT


@dataclass(frozen=True)
class Reaction:
    """What is done once per violation, by the handler that evaluated it."""

    publish: Publish | None = None
    call: Call | None = None

    def types(self) -> list[tuple[str, str]]:
        """(``publish`` or ``call``, the message or service type it uses), each written."""
        return [
            *([("publish", self.publish.msg_type)] if self.publish is not None else []),
            *([("call", self.call.srv_type)] if self.call is not None else []),
        ]

    def describe(self) -> str:
        parts = []
        if self.publish is not None:
            parts.append(f"publish {self.publish.msg_type} on {self.publish.topic}")
        if self.call is not None:
            parts.append(f"call {self.call.service} ({self.call.srv_type})")
        return " and ".join(parts)


def value_fits(value: Scalar, kind: ValueKind) -> bool:
    """Whether ``value`` (from YAML) can be a ``kind`` field: an int is a float too, a bool
    is neither."""
    if kind == "bool":
        return isinstance(value, bool)
    if kind == "string":
        return isinstance(value, str)
    if isinstance(value, bool):
        return False
    if kind == "int":
        return isinstance(value, int)
    return isinstance(value, int | float)


def request_type(srv_type: str) -> str:
    """The request message type of a service type: ``pkg/srv/Name`` -> ``pkg/srv/Name_Request``."""
    return f"{srv_type}_Request"
