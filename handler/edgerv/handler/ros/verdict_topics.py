"""The verdict topics. Typed, when edgerv_msgs is installed (interfaces/build.sh):
``edgerv_msgs/msg/Verdict`` on ``/edgerv/verdict``, each verdict as reached, and
``edgerv_msgs/msg/VerdictArray`` on ``/edgerv/last_verdicts``, the last verdict of every
monitor of this handler, for subscribers that come late (docs/handler.md, "Typed
verdicts"); and as JSON in ``std_msgs/msg/String`` on ``/edgerv/verdicts``, kept for
compatibility."""

from __future__ import annotations

import json
import logging
import threading
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

from edgerv.core.pipeline import Verdict
from edgerv.handler.engine import Engine
from edgerv.handler.outbox import Burst
from edgerv.handler.ros.cdr_out import CDR_LE, VerdictFields, encode_verdict, encode_verdict_array
from edgerv.handler.ros.messages import message_class
from edgerv.handler.sinks import verdict_record

log = logging.getLogger("edgerv.handler.ros")

VERDICT_TOPIC = "/edgerv/verdicts"  # JSON in std_msgs/String: kept for compatibility
BUILD_MSGS = (
    "edgerv_msgs is not installed in this Python environment: no typed verdicts on "
    f"/edgerv/verdict and /edgerv/last_verdicts (the JSON on {VERDICT_TOPIC} goes "
    "on); build it from edgerv's source tree with `make install`, or `bash "
    "interfaces/build.sh <venv>` for another venv"
)

TYPED_VERDICT_TOPIC = "/edgerv/verdict"  # edgerv_msgs/msg/Verdict, each as reached
LAST_VERDICTS_TOPIC = "/edgerv/last_verdicts"  # edgerv_msgs/msg/VerdictArray, per handler
# A late subscriber (transient local) gets the recent verdicts on /edgerv/verdict, and the
# newest array of each handler on /edgerv/last_verdicts: with it, each monitor's last one.
TYPED_VERDICT_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=100,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
LAST_VERDICTS_QOS = QoSProfile(
    history=HistoryPolicy.KEEP_LAST,
    depth=1,
    reliability=ReliabilityPolicy.RELIABLE,
    durability=DurabilityPolicy.TRANSIENT_LOCAL,
)
LAST_VERDICTS_SECONDS = 0.2  # the array is checked (and published if changed) this often


@dataclass
class _Kept:
    """A monitor's last verdict written on /edgerv/verdict: its fields and bytes."""

    verdict: Verdict
    fields: VerdictFields
    cdr: bytes  # encode_verdict(*fields) at offset 0


class TypedVerdicts:
    """The typed verdict topics: ``/edgerv/verdict`` (``edgerv_msgs/msg/Verdict``), each
    verdict as reached (:meth:`write`, in the scheduler's thread, as a verdict sink), and
    ``/edgerv/last_verdicts`` (``edgerv_msgs/msg/VerdictArray``), this handler's last
    verdict of every monitor defined on it that has one (:meth:`refresh`, in a thread of
    its own every LAST_VERDICTS_SECONDS, published when its content changed). Both
    transient local: a late subscriber gets the recent verdicts and the newest array.

    Both publish CDR made here: rclpy would convert a Python object per verdict to C (70
    ms for an array of 10,000); each verdict is encoded once, when written, and an array
    joins the bytes kept (about 3 ms for 10,000: docs/handler.md)."""

    def __init__(self, node: Any, engine: Engine, verdict_type: Any, array_type: Any) -> None:
        self.engine = engine
        self.clock = node.get_clock()  # ROS time: /clock's under --use-sim-time
        self.each = node.create_publisher(verdict_type, TYPED_VERDICT_TOPIC, TYPED_VERDICT_QOS)
        self.last = node.create_publisher(array_type, LAST_VERDICTS_TOPIC, LAST_VERDICTS_QOS)
        self._lock = threading.Lock()  # write() and refresh() both change _kept
        self._kept: dict[str, _Kept] = {}  # monitor -> its last verdict written
        self.written = 0  # verdicts written: refresh() looks again when the count moves
        self._seen: tuple[int, int] | None = None  # (written, routes_version) looked at
        self._published: list[VerdictFields] | None = None  # the last array's verdicts
        self.arrays = 0  # arrays published

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        """Publish each verdict on /edgerv/verdict, with its monitor's assertion and
        epoch as they are now (the verdict was reached a moment ago), and keep it.

        Read without the engine's lock: each is one attribute of the slot, which the
        engine replaces whole (a definition, an epoch), so what is read is what the lock
        would have given a moment earlier or later. Under the lock, this lane waited
        behind the take loop and the scheduler for a quarter of its time at 10,000
        monitors, and the verdicts after these waited with it (bench/scale.py)."""
        slots = self.engine.slots
        kept = []
        publish = self.each.publish
        for v in verdicts:
            slot = slots.get(v.monitor)  # None: removed since it was reached
            if slot is None:
                assertion, epoch = "", 0
            else:
                assertion, epoch = slot.compiled.spec.assertion, slot.epoch
            fields = (v.monitor, v.verdict, v.stamp, v.step, handler, assertion, epoch)
            cdr = encode_verdict(*fields)
            publish(CDR_LE + cdr)
            kept.append(_Kept(v, fields, cdr))
        with self._lock:
            for k in kept:
                self._kept[k.verdict.monitor] = k
            self.written += len(kept)

    def refresh(self, now_ns: int | None = None) -> bool:
        """Publish the array if its content changed since the last one (the first time
        too, empty or not: each handler has one); True if it did. Cheap when nothing
        happened: a verdict written or a monitor added, removed or redefined (the engine's
        routes_version) since the last look is what makes it look again."""
        engine = self.engine
        seen = (self.written, engine.routes_version)
        if seen == self._seen:
            return False
        monitors_changed = self._seen is None or seen[1] != self._seen[1]
        self._seen = seen
        kept = self._kept
        items: list[_Kept | tuple[Verdict, str, int]] = []
        # without the engine's lock, as write() reads them: a few ms for 10,000 monitors
        # that the take loop and the scheduler no longer wait for (the slots listed at once)
        slots = list(engine.slots.values())
        for slot in slots:
            v = slot.last_verdict
            if v is None:
                continue
            k = kept.get(v.monitor)
            if k is not None and k.verdict is v:
                items.append(k)
            else:  # reached, not written yet: encoded here (written soon after)
                items.append((v, slot.compiled.spec.assertion, slot.epoch))
        names = {slot.name for slot in slots} if monitors_changed else None
        if names is not None:  # forget the monitors removed
            with self._lock:
                for name in [n for n in self._kept if n not in names]:
                    del self._kept[name]
        handler = engine.name
        fields: list[VerdictFields] = []
        encoded: list[bytes] = []
        for item in items:
            if isinstance(item, _Kept):
                fields.append(item.fields)
                encoded.append(item.cdr)
            else:
                v, assertion, epoch = item
                f = (v.monitor, v.verdict, v.stamp, v.step, handler, assertion, epoch)
                fields.append(f)
                encoded.append(b"")  # encoded below, if the array is published
        if fields == self._published:  # (the same tuples, mostly: compared by identity)
            return False
        encoded = [e or encode_verdict(*f) for e, f in zip(encoded, fields, strict=True)]
        stamp = self.clock.now().nanoseconds if now_ns is None else now_ns
        self.last.publish(encode_verdict_array(stamp, handler, fields, encoded))
        self._published = fields
        self.arrays += 1
        return True


def typed_verdicts(node: Any, engine: Engine) -> TypedVerdicts | None:
    """The typed verdict topics on ``node``, or None (with a warning) without edgerv_msgs."""
    try:
        verdict_type = message_class("edgerv_msgs/msg/Verdict")
        array_type = message_class("edgerv_msgs/msg/VerdictArray")
    except ImportError:
        log.warning(BUILD_MSGS)
        return None
    try:  # (the typesupport libraries load here)
        return TypedVerdicts(node, engine, verdict_type, array_type)
    except Exception as exc:
        log.warning(
            "edgerv_msgs is installed but its typesupport does not load (%s): no typed "
            "verdicts (the JSON on %s goes on); rebuild it: `make install`",
            exc,
            VERDICT_TOPIC,
        )
        return None


class VerdictTopics:
    """A verdict sink (a lane of the outbox): the JSON on /edgerv/verdicts and the typed
    topics (:class:`TypedVerdicts`, without edgerv_msgs none), whose /edgerv/last_verdicts
    is refreshed by :meth:`start`'s thread until ``stop`` is set."""

    def __init__(self, node: Any, engine: Engine, stop: threading.Event) -> None:
        from std_msgs.msg import String

        self._string = String
        self.verdicts = node.create_publisher(
            String, VERDICT_TOPIC, QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        )
        self.typed = typed_verdicts(node, engine)
        self._stop = stop
        self._failures = 0
        self._thread: threading.Thread | None = None

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        """One std_msgs/String with a JSON object per verdict on /edgerv/verdicts (kept
        for compatibility), and each verdict typed on /edgerv/verdict."""
        for v in verdicts:
            self.verdicts.publish(self._string(data=json.dumps(verdict_record(handler, v))))
        if self.typed is not None:
            self.typed.write(handler, verdicts)

    def write_bursts(self, handler: str, bursts: Sequence[Burst[Verdict]]) -> None:
        """Bursts a lane coalesced (this sink fell behind): on /edgerv/verdicts each one's
        first verdict, and its last with ``"coalesced": N``, the monitor's verdicts between
        them that are not published; typed, the first and the last."""
        string, publish = self._string, self.verdicts.publish
        for b in bursts:
            publish(string(data=json.dumps(verdict_record(handler, b.first))))
            if b.count > 1:
                last = verdict_record(handler, b.last)
                last["coalesced"] = b.between
                publish(string(data=json.dumps(last)))
        if self.typed is not None:
            self.typed.write(handler, [v for b in bursts for v in b.ends])

    def start(self) -> None:
        """The /edgerv/last_verdicts thread, with the typed topics."""
        if self.typed is not None:
            self._thread = threading.Thread(
                target=self._last_verdicts_loop,
                args=(self.typed,),
                name="edgerv-last-verdicts",
                daemon=True,
            )
            self._thread.start()

    def _last_verdicts_loop(self, typed: TypedVerdicts) -> None:
        """The /edgerv/last_verdicts thread: a look every LAST_VERDICTS_SECONDS (nothing
        to do unless a verdict was written or a monitor came or went), the first at once."""
        while True:
            try:
                typed.refresh()
            except Exception:  # retried next time; it must not stop the handler
                self._failures += 1
                n = self._failures
                if n in (1, 10, 100) or n % 1000 == 0:
                    log.exception("publishing %s failed (%d times)", LAST_VERDICTS_TOPIC, n)
            if self._stop.wait(LAST_VERDICTS_SECONDS):
                return

    def join(self, timeout: float) -> None:
        if self._thread is not None:
            self._thread.join(timeout=timeout)
