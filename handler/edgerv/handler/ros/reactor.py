"""Monitors' reactions on ROS (``spec.onViolation``): a message published, a service called.

The engine hands the reactor each violation of a monitor that reacts, once: a violation is
evaluated on one handler only (the handoff's guarantee, docs/protocol.md), so the
reaction is done once, by the handler that ran the monitor at that moment. A message is
published at once, from the thread that evaluated the violation (the scheduler's); a
service is called by a thread of the reactor's (it waits for the service, up to its
timeout, and for the answer), so a slow service never holds verdicts back.

Publishers and clients are made on first use, one per topic or service, on a node of the
reactor's own (``edgerv_<handler>_reactions``), which an executor of its own spins for
the services' answers.
"""

from __future__ import annotations

import logging
import queue
import threading
import time
from collections.abc import Callable, Sequence
from typing import Any

import rclpy
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from edgerv.core.pipeline import Verdict
from edgerv.core.reactions import Call, Fields, Publish, Reaction
from edgerv.handler.ros.messages import message_class
from edgerv.handler.ros.node import node_name

log = logging.getLogger("edgerv.handler.reactor")

# What a reaction publishes with: `ros2 topic pub`'s profile (reliable, volatile, 10); a
# best-effort subscriber (a controller's /cmd_vel) receives it too.
REACTION_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=10,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.VOLATILE,
)
QUEUED_CALLS = 1000  # calls waiting for the caller thread; past it, a call is dropped (logged)
# At shutdown the calls queued are still made, for at most this long in all (the pod's
# grace period is 30 s by default); those left then are not made (logged, counted).
CLOSE_SECONDS = 5.0
POLL_SECONDS = 0.02  # how often a call looks for its server, its answer, the deadline


def build_message(cls: Any, fields: Fields) -> Any:
    """A ``cls`` message with ``fields`` set (dotted paths; the rest default). The values
    were checked against the type's definition (edgerv.core.documents); a number is made
    the field's Python type here (``0`` for a float field), and rclpy's own setters refuse
    what is out of the field's range (ValueError, AssertionError, TypeError)."""
    msg = cls()
    for path, value in fields:
        *parents, leaf = path.split(".")
        obj = msg
        for name in parents:
            obj = getattr(obj, name)
        current = getattr(obj, leaf)
        if isinstance(current, float) and not isinstance(value, bool):
            value = float(value)
        setattr(obj, leaf, value)
    return msg


class Reactor:
    """Does reactions on ROS for one handler (an engine's ``reactor``). Thread-safe."""

    def __init__(
        self, handler: str, on_outcome: Callable[[str, str | None], None] | None = None
    ) -> None:
        # each reaction's outcome: (monitor, None) done, (monitor, why) not (the engine's
        # note_reaction: counted in /diagnostics)
        self.on_outcome = on_outcome
        self.node = rclpy.create_node(node_name(handler) + "_reactions")
        self._executor = SingleThreadedExecutor()
        self._executor.add_node(self.node)
        self._lock = threading.Lock()
        self._publishers: dict[tuple[str, str], Any] = {}
        self._clients: dict[tuple[str, str], Any] = {}
        self._messages: dict[Publish, Any] = {}
        self._calls: queue.Queue[tuple[Verdict, Call] | None] = queue.Queue(QUEUED_CALLS)
        self._deadline: float | None = None  # (monotonic) set by close: calls end by then
        self._spinner = threading.Thread(target=self._spin, name="edgerv-reactor-spin", daemon=True)
        self._caller = threading.Thread(target=self._call_loop, name="edgerv-reactor", daemon=True)
        self._spinner.start()
        self._caller.start()

    # -- what the engine calls -----------------------------------------------------------------

    def prepare(self, reaction: Reaction) -> None:
        """Make the reaction's publisher, message and client (when a monitor is defined):
        subscribers and servers match them before any violation. A problem is logged, and
        told again at the violation."""
        try:
            if reaction.publish is not None:
                self._publisher(reaction.publish)
            if reaction.call is not None:
                self._client(reaction.call)
        except Exception as exc:
            log.error("cannot prepare the reaction to %s: %s", reaction.describe(), exc)

    def react(self, handler: str, due: Sequence[tuple[Verdict, Reaction]]) -> None:
        for verdict, reaction in due:
            if reaction.publish is not None:
                self._publish(verdict, reaction.publish)
            if reaction.call is not None:
                try:
                    self._calls.put_nowait((verdict, reaction.call))
                except queue.Full:
                    self._outcome(verdict.monitor, f"{QUEUED_CALLS} calls already waited")
                    log.error(
                        "monitor %s violated at step %d: %d service calls already wait: "
                        "%s not called",
                        verdict.monitor,
                        verdict.step,
                        QUEUED_CALLS,
                        reaction.call.service,
                    )

    # -- publishing ----------------------------------------------------------------------------

    def _publisher(self, p: Publish) -> tuple[Any, Any]:
        """The publisher of ``p`` and its message, made once."""
        with self._lock:
            msg = self._messages.get(p)
            if msg is None:
                msg = self._messages[p] = build_message(message_class(p.msg_type), p.fields)
            key = (p.topic, p.msg_type)
            pub = self._publishers.get(key)
            if pub is None:
                pub = self._publishers[key] = self.node.create_publisher(
                    type(msg), p.topic, REACTION_QOS
                )
            return pub, msg

    def _client(self, call: Call) -> Any:
        """The client of ``call``'s service, made once."""
        with self._lock:
            key = (call.service, call.srv_type)
            client = self._clients.get(key)
            if client is None:
                srv = message_class(call.srv_type)
                client = self._clients[key] = self.node.create_client(srv, call.service)
            return client

    def _publish(self, verdict: Verdict, p: Publish) -> None:
        try:
            pub, msg = self._publisher(p)
            pub.publish(msg)
        except Exception as exc:  # a type gone, a value out of range, the node closing
            self._outcome(verdict.monitor, f"cannot publish on {p.topic}: {exc}")
            log.error(
                "monitor %s violated at step %d: cannot publish %s on %s: %s",
                verdict.monitor,
                verdict.step,
                p.msg_type,
                p.topic,
                exc,
            )
            return
        self._outcome(verdict.monitor, None)
        log.info(
            "monitor %s violated at step %d: published %s on %s",
            verdict.monitor,
            verdict.step,
            p.msg_type,
            p.topic,
        )

    # -- calling -------------------------------------------------------------------------------

    def _call_loop(self) -> None:
        while True:
            item = self._calls.get()
            if item is None:
                return
            verdict, call = item
            if self._deadline is not None and time.monotonic() >= self._deadline:
                if self._abandon([item]):
                    return  # (it took the close's None from the queue)
                continue
            try:
                failure, answer = self._call(call)
            except Exception as exc:  # a type gone, a value out of range, the node closing
                failure, answer = f"failed: {exc}", ""
            where = f"monitor {verdict.monitor} violated at step {verdict.step}"
            self._outcome(verdict.monitor, None if failure is None else f"{call.service} {failure}")
            if failure is not None:
                log.error("%s: the call of %s %s", where, call.service, failure)
                continue
            log.info("%s: called %s (%s)%s", where, call.service, call.srv_type, answer)

    def _call(self, call: Call) -> tuple[str | None, str]:
        """Call the service: (None, what it answered) when it answered, else (what went
        wrong, "")."""
        client = self._client(call)
        until = time.monotonic() + call.timeout
        if not self._wait(client.service_is_ready, until):
            return f"found no server within {self._waited(call)}", ""
        answered = threading.Event()
        future = client.call_async(build_message(client.srv_type.Request, call.fields))
        future.add_done_callback(lambda _: answered.set())
        if not self._wait(answered, until):
            client.remove_pending_request(future)
            return f"had no answer within {self._waited(call)}", ""
        response = future.result()
        fields = [
            f"{name} {getattr(response, name)!r}"
            for name in ("success", "message")
            if hasattr(response, name)
        ]
        if getattr(response, "success", True) is False:
            log.warning("service %s answered success False: %s", call.service, fields)
        return None, f": it answered {', '.join(fields)}" if fields else ""

    def _wait(self, done: Callable[[], bool] | threading.Event, until: float) -> bool:
        """Whether ``done`` (a test, or an event: woken at once when set) holds before
        ``until`` (monotonic) or the close's deadline."""
        test = done.is_set if isinstance(done, threading.Event) else done
        while not test():
            now = time.monotonic()
            end = until if self._deadline is None else min(until, self._deadline)
            if now >= end:
                return False
            if isinstance(done, threading.Event):
                done.wait(min(POLL_SECONDS, end - now))
            else:
                time.sleep(min(POLL_SECONDS, end - now))
        return True

    def _waited(self, call: Call) -> str:
        if self._deadline is not None and time.monotonic() >= self._deadline:
            return f"the {CLOSE_SECONDS:g} s the handler gives its calls when it stops"
        return f"{call.timeout:g} s"

    def _abandon(self, items: list[tuple[Verdict, Call] | None]) -> bool:
        """Calls not made: the handler stopped (what else waits in the queue too). True
        when the close's None was among them."""
        while True:
            try:
                items.append(self._calls.get_nowait())
            except queue.Empty:
                break
        left = [i for i in items if i is not None]
        for verdict, call in left:
            self._outcome(verdict.monitor, f"{call.service} not called: the handler stopped")
        if left:
            log.error(
                "%d service call(s) of reactions not made: the handler stopped (it gives its "
                "calls %g s): %s",
                len(left),
                CLOSE_SECONDS,
                ", ".join(sorted({f"{v.monitor} -> {c.service}" for v, c in left})),
            )
        return len(left) < len(items)

    # -- running -------------------------------------------------------------------------------

    def _spin(self) -> None:
        try:
            self._executor.spin()
        except Exception:  # the context shut down under it
            log.debug("the reactor's executor stopped", exc_info=True)

    def _outcome(self, monitor: str, problem: str | None) -> None:
        if self.on_outcome is not None:
            self.on_outcome(monitor, problem)

    def close(self) -> None:
        """Make the calls queued, within CLOSE_SECONDS in all (each within its own
        timeout too); those left then are not made (logged). Then stop."""
        self._deadline = time.monotonic() + CLOSE_SECONDS
        self._calls.put(None)
        self._caller.join(timeout=CLOSE_SECONDS + 5)
        self._executor.shutdown(timeout_sec=1)
        self._spinner.join(timeout=5)
        self.node.destroy_node()
