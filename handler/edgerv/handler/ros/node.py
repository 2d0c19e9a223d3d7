"""The handler's ROS node and its lifecycle: rclpy started and shut down in this process,
the node made with its pieces, their threads started and stopped, the node destroyed.

The pieces, a module each: the subscriptions and their QoS (:mod:`.subscriptions`), the
take loop that feeds the engine (:mod:`.take`), ``--deadline``'s topic (:mod:`.deadline`),
the graph thread (:mod:`.graph`), /clock under ``--use-sim-time`` (:mod:`.sim_time`),
the verdict topics (:mod:`.verdict_topics`), /diagnostics (:mod:`.diagnostics`) and
/rosout (:mod:`.rosout`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import rclpy
from rclpy.signals import SignalHandlerOptions
from rclpy.utilities import ok, try_shutdown

from edgerv.handler.clock import SimClock
from edgerv.handler.engine import Engine
from edgerv.handler.health import Health
from edgerv.handler.outbox import Outbox
from edgerv.handler.ros.deadline import DeadlineTopic
from edgerv.handler.ros.diagnostics import Diagnostics
from edgerv.handler.ros.graph import GraphWatch
from edgerv.handler.ros.logs import ros_log_problem
from edgerv.handler.ros.rosout import Rosout
from edgerv.handler.ros.sim_time import ClockNote, follow_clock
from edgerv.handler.ros.subscriptions import Subscriptions
from edgerv.handler.ros.take import TakeLoop
from edgerv.handler.ros.verdict_topics import VerdictTopics

log = logging.getLogger("edgerv.handler.ros")

JOIN_SECONDS = 10  # each thread's at stop


def init_ros() -> None:
    """Start rclpy without its signal handlers (the handler's main() owns SIGINT/SIGTERM)
    and without ROS's console output: the handler's log lines reach stderr through
    Python's logging as they always did, and /rosout through the node's logger
    (:class:`~edgerv.handler.ros.rosout.RosoutHandler`); ROS's console would print each
    of them a second time."""
    if not ok():
        no_files = ros_log_problem()  # (logs: a home rcl cannot write)
        if no_files:
            log.warning(no_files)
        rclpy.init(
            args=["edgerv", "--ros-args", "--disable-stdout-logs"]
            + (["--disable-external-lib-logs"] if no_files else []),
            signal_handler_options=SignalHandlerOptions.NO,
        )


def shutdown_ros() -> None:
    """Shut rclpy down, unless it is down already: the handler's last step."""
    try_shutdown()


def node_name(name: str) -> str:
    """The handler's node name: ``edgerv_`` and its name, each other character ``_``."""
    clean = "".join(c if c.isalnum() else "_" for c in name)
    return f"edgerv_{clean}"


class HandlerNode:
    """The handler's ROS node, made with its pieces: :attr:`subscriptions`, :attr:`take`
    (the take loop), :attr:`deadline` (with --deadline), :attr:`graph`, :attr:`verdicts`
    (a verdict sink), :attr:`diagnostics` (given ``health`` whose config's period is above
    0) and :attr:`rosout`. :meth:`start` starts their threads, :meth:`stop` stops them
    (one event for all), :meth:`close` destroys the node."""

    def __init__(
        self,
        engine: Engine,
        name: str,
        reorder_window: float = 0.02,
        health: Health | None = None,
        outbox: Outbox | None = None,
    ) -> None:
        self.engine = engine
        self.node = rclpy.create_node(node_name(name))
        self._stop = threading.Event()
        # --use-sim-time: ROS time from /clock (stamps of unstamped messages, the instant
        # everything is taken up to); None: the system clock's
        self.sim = engine.clock if isinstance(engine.clock, SimClock) else None
        self._time_source = None if self.sim is None else follow_clock(self.node, self.sim)
        self.verdicts = VerdictTopics(self.node, engine, self._stop)
        self.wakeup = self.node.create_guard_condition(lambda: None)  # wakes the take loop
        engine.wake_ingest = self.wake  # (the scheduler's: how far is everything taken?)
        self.subscriptions = Subscriptions(self.node, engine, self.wake)
        self.deadline = (
            DeadlineTopic(engine.deadline, self.node, self.subscriptions, self.sim, self.wake)
            if engine.deadline is not None
            else None
        )
        if self.deadline is not None:
            self.deadline.namespace = engine.robot_namespace
        self.take = TakeLoop(
            self.node,
            engine,
            self.subscriptions,
            self.deadline,
            self.wakeup,
            self._stop,
            reorder_window,
            self.sim,
        )
        checks: list[Callable[[], None]] = [self.subscriptions.check_qos]
        if self.deadline is not None:
            checks.append(self.deadline.learn_type)
        if self.sim is None:
            checks.append(ClockNote(self.node).check)
        self.graph = GraphWatch(checks, self._stop)
        self.rosout = Rosout(self.node)
        self.diagnostics: Diagnostics | None = None
        if health is not None and health.config.period > 0:
            self.diagnostics = Diagnostics(
                self.node, engine, health, self.subscriptions, self.rosout, outbox, self._stop
            )

    def start(self, on_failure: Callable[[], None]) -> None:
        """Start the pieces' threads; ``on_failure`` is called if the take loop dies."""
        self.take.start(on_failure)
        self.graph.start()
        if self.diagnostics is not None:
            self.diagnostics.start()
        self.verdicts.start()

    def wake(self) -> None:
        """Wake the take loop: the routes changed, or a subscription is to be made."""
        self.wakeup.trigger()

    def stop(self) -> None:
        """Stop every thread, each joined for JOIN_SECONDS at most."""
        self._stop.set()
        self.wake()
        if self.diagnostics is not None:
            self.diagnostics.wake()
        self.take.join(JOIN_SECONDS)
        self.graph.join(JOIN_SECONDS)
        if self.diagnostics is not None:
            self.diagnostics.join(JOIN_SECONDS)
        self.verdicts.join(JOIN_SECONDS)

    def close(self) -> None:
        self.engine.wake_ingest = lambda: None  # (the guard condition goes with the node)
        self.rosout.close()  # before the node goes
        if self.sim is not None:
            self.sim.detach()
        self.node.destroy_node()
