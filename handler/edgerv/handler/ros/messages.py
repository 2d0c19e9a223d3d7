"""The rclpy class of a message type: installed, else built from the robot's own
definitions (:mod:`edgerv.handler.ros.types`)."""

from __future__ import annotations

import importlib
from typing import Any

from edgerv.handler.ros import types as ros_types


def message_class(msg_type: str) -> Any:
    """The rclpy class of ``pkg/msg/Type`` (or of a service's event, ``pkg/srv/Name_Event``,
    in its package's ``srv`` module). A type not installed, of a package of the robot's
    own, is built from its .msg files where ``edgerv check`` finds them (at its first use,
    cached: :mod:`edgerv.handler.ros.types`); raises ImportError saying what to do."""
    pkg, kind, name = msg_type.split("/")
    try:
        return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
    except (ImportError, AttributeError):
        return ros_types.message_class(msg_type)


def type_problem(msg_type: str) -> str | None:
    """Why ``msg_type`` has no class here (what :func:`message_class` raises), or None."""
    try:
        message_class(msg_type)
    except ImportError as exc:
        return str(exc)
    return None
