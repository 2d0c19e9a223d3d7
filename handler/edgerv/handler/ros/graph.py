"""The graph thread (``edgerv-qos``): the ROS graph asked once a second, off the take loop
(graph queries take time, and locks the middleware's own threads hold): the checks of
the pieces that need it (the subscriptions' publishers and QoS, --deadline's type, a
/clock published while on the system clock)."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence

log = logging.getLogger("edgerv.handler.ros")

QOS_CHECK_SECONDS = 1.0


class GraphWatch:
    """Runs ``checks``, in order, every QOS_CHECK_SECONDS in a thread of its own until
    ``stop`` is set; a check that fails is logged and the round ends (all are retried
    at the next)."""

    def __init__(self, checks: Sequence[Callable[[], None]], stop: threading.Event) -> None:
        self.checks = tuple(checks)
        self._stop = stop
        self._thread: threading.Thread | None = None

    def start(self) -> None:
        self._thread = threading.Thread(target=self._run, name="edgerv-qos", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while not self._stop.wait(QOS_CHECK_SECONDS):
            try:
                for check in self.checks:
                    check()
            except Exception:  # a failed check is retried; it must not stop the handler
                log.exception("QoS check failed")

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout)
