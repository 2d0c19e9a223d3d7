"""/rosout: the handler's log lines, sent through its node's rclpy logger (rcutils)."""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
from typing import Any

from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy

# Python's levels -> rcutils' severities (DEBUG, INFO, WARN, ERROR, FATAL: 10 to 50)
_SEVERITIES = (
    (logging.CRITICAL, 50),
    (logging.ERROR, 40),
    (logging.WARNING, 30),
    (logging.INFO, 20),
)


def ros_severity(levelno: int) -> int:
    """The rcutils severity of a Python logging level: DEBUG, INFO, WARNING, ERROR and
    CRITICAL map to DEBUG, INFO, WARN, ERROR and FATAL (a level between two, down)."""
    return next((severity for at, severity in _SEVERITIES if levelno >= at), 10)


class RosoutHandler(logging.Handler):
    """A logging handler that hands each record to the node's rclpy logger (rcutils),
    which publishes it on /rosout under the node's name (and writes ROS's log file).

    Safe from any thread (logging serializes a handler's calls under its lock). It never
    raises and never logs: a line that cannot be sent is counted in :attr:`failures`
    (the handler's diagnostic status shows it) and the first failure is written to
    stderr directly, not through logging, which would come back here. A record logged
    while one is being sent (from within rclpy) is not sent, and a forked child (the
    Spot worker) sends nothing: the node is its parent's."""

    def __init__(self, logger_name: str) -> None:
        super().__init__()
        self.logger_name = logger_name
        self.failures = 0
        self._pid = os.getpid()
        self._sending = threading.local()

    def emit(self, record: logging.LogRecord) -> None:
        if os.getpid() != self._pid or getattr(self._sending, "on", False):
            return
        self._sending.on = True
        try:
            _rclpy.rclpy_logging_rcutils_log(
                ros_severity(record.levelno),
                self.logger_name,
                self.format(record),  # the message, and its traceback if any
                record.funcName or "",
                record.pathname or "",
                record.lineno or 0,
            )
        except Exception as exc:  # never into logging: it would come back here
            self.failures += 1
            if self.failures == 1:
                with contextlib.suppress(Exception):
                    sys.stderr.write(f"edgerv: a log line could not be sent to /rosout: {exc!r}\n")
        finally:
            self._sending.on = False

    def handleError(self, record: logging.LogRecord) -> None:
        self.failures += 1  # (logging's own would print a traceback for each)


class Rosout:
    """The node's /rosout: what a Python logger logs, forwarded once :meth:`forward` is
    called, until :meth:`close`."""

    def __init__(self, node: Any) -> None:
        self.node = node
        self.handler: RosoutHandler | None = None
        self._logger: logging.Logger | None = None

    @property
    def failures(self) -> int:
        """Log lines that could not be sent (/diagnostics shows them)."""
        return self.handler.failures if self.handler else 0

    def forward(self, logger: logging.Logger) -> RosoutHandler:
        """Send what ``logger`` (and its children) log to /rosout too, under this node's
        name, from the level Python's logging lets through (the node's rcutils logger is
        set to the same level: the default INFO would hold DEBUG back)."""
        ros_logger = self.node.get_logger()
        ros_logger.set_level(ros_severity(logger.getEffectiveLevel()))
        self.handler = RosoutHandler(ros_logger.name)
        self._logger = logger
        logger.addHandler(self.handler)
        return self.handler

    def close(self) -> None:
        """Forward no more: before the node goes."""
        if self.handler is not None and self._logger is not None:
            self._logger.removeHandler(self.handler)
