"""Coverage-guided fuzzing (atheris, libFuzzer) of the control API's requests as bytes.

A real :class:`~edgerv.handler.api.ControlApi` (its app, its gate, its admission, its
handlers) over an engine with two monitors (``m`` runs here, ``n`` is being received in
the handoff of epoch 7), fed bytes through a connection of its own pool over an
in-memory transport: no sockets, no threads (the API's workers run inline), no timing.
The first byte of an input picks how the rest is cut into reads (0: at once; else reads
of that many bytes), the rest is what a client sends: request heads, bodies (chunked or
not, Monitor documents, handoff steps, snapshot bundles), pipelined. Whatever the bytes,
every answer is HTTP/1.1 with a JSON body (``/metrics``: Prometheus text; a release: its
snapshot bundle), none a 5xx but
503, nothing is logged at ERROR (aiohttp logs there what its handlers raise: a 500) and
no exception reaches the event loop::

    python tests/fuzz/fuzz_api.py WORK_CORPUS tests/fuzz/corpus/api \
        -dict=tests/fuzz/api.dict -max_total_time=60

``make fuzz`` runs it (``FUZZ_SECONDS``); ``tests/unit/test_fuzz_targets.py`` runs it for
a few thousand inputs and replays every input in ``tests/fuzz/crashes/api/`` through
:func:`fuzz_one_input`. tests/fuzz/make_corpus.py writes its seeds.
"""

from __future__ import annotations

import asyncio
import concurrent.futures
import importlib
import json
import logging
import sys
from collections.abc import Callable
from typing import Any

TOKEN = "fuzz-token"
EPOCH = 7  # the handoff ``n`` is received in
DOCUMENT = """\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {name: NAME}
spec:
  assertion: "always (a -> x < 5)"
  signals:
    a: {topic: /a, type: std_msgs/msg/Bool}
    x: {topic: /x, type: std_msgs/msg/Float64}
"""
SPINS = 30  # rounds of the event loop after each read (inline work needs a few)

_state: dict[str, Any] = {}


class Inline(concurrent.futures.ThreadPoolExecutor):
    """An executor that runs its calls at once, on the caller's thread (the API's workers,
    here; asyncio takes a ThreadPoolExecutor only, which starts no thread until asked)."""

    def submit(self, fn: Callable[..., Any], /, *args: Any, **kwargs: Any) -> Any:
        future: concurrent.futures.Future[Any] = concurrent.futures.Future()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # handed to the awaiting handler
            future.set_exception(exc)
        return future


class MemoryTransport(asyncio.Transport):
    """What the API writes, kept; closing tells the protocol at the loop's next round."""

    def __init__(self, loop: asyncio.AbstractEventLoop, protocol: asyncio.Protocol) -> None:
        super().__init__()
        self.loop, self.protocol = loop, protocol
        self.out = bytearray()
        self.closed = False

    def get_extra_info(self, name: str, default: Any = None) -> Any:
        return {"peername": ("127.0.0.9", 40000), "sockname": ("127.0.0.1", 8470)}.get(
            name, default
        )

    def write(self, data: Any) -> None:
        if not self.closed:
            self.out += data

    def writelines(self, lines: Any) -> None:
        for data in lines:
            self.write(data)

    def is_closing(self) -> bool:
        return self.closed

    def close(self) -> None:
        if not self.closed:
            self.closed = True
            self.loop.call_soon(self.protocol.connection_lost, None)

    def abort(self) -> None:
        self.close()

    def get_protocol(self) -> Any:
        return self.protocol

    def set_protocol(self, protocol: Any) -> None:
        self.protocol = protocol

    def pause_reading(self) -> None:
        pass

    def resume_reading(self) -> None:
        pass

    def is_reading(self) -> bool:
        return not self.closed

    def can_write_eof(self) -> bool:
        return True

    def write_eof(self) -> None:
        pass

    def get_write_buffer_size(self) -> int:
        return 0


class Errors(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.seen: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.seen.append(record.getMessage())


def load() -> None:
    """The loop, the API and its pool, and the two monitors compiled (once)."""
    if _state:
        return
    from prometheus_client import CollectorRegistry

    from edgerv.core.documents import load_monitors_text
    from edgerv.core.monitor import compile_monitor
    from edgerv.handler import api as api_module
    from edgerv.handler.engine import Engine
    from edgerv.handler.limits import Limits

    loop = asyncio.new_event_loop()
    asyncio.set_event_loop(loop)
    loop.set_default_executor(Inline())
    errors = Errors()
    for name in ("edgerv", "aiohttp"):
        logging.getLogger(name).addHandler(errors)
    loop.set_exception_handler(lambda _loop, context: errors.seen.append(str(context)))
    api_module.MAX_WAIT = 0.0  # a release answers at once
    monitors = {
        name: compile_monitor(load_monitors_text(name, DOCUMENT.replace("NAME", name))[0])
        for name in ("m", "n")
    }
    limits = Limits(bundle=4 << 20, bodies=16 << 20)
    api = api_module.ControlApi(
        Engine("fuzz"), CollectorRegistry(), TOKEN, lambda: None, limits=limits
    )
    api._work = api._scraper = Inline()
    pool = loop.run_until_complete(api.prepare())
    _state.update(loop=loop, api=api, pool=pool, monitors=monitors, errors=errors, Engine=Engine)


def fresh_engine() -> Any:
    """An engine as each input finds it: ``m`` runs, ``n`` is received under EPOCH."""
    engine = _state["Engine"]("fuzz", flush_after=1e9)
    engine.put(_state["monitors"]["m"], active=True)
    engine.put(_state["monitors"]["n"], active=False)
    engine.handoffs.receive("n", EPOCH)
    return engine


def answers(data: bytes) -> list[tuple[int, bytes, bytes]]:
    """The answers in what the API wrote, each whole one: status, head, body."""
    out = []
    while data:
        top, sep, rest = data.partition(b"\r\n\r\n")
        if not sep:
            break
        assert top.startswith(b"HTTP/"), top[:200]  # (1.1; 1.0 or 0.9 when asked so)
        length = 0
        for line in top.split(b"\r\n")[1:]:
            name, _, value = line.partition(b":")
            if name.strip().lower() == b"content-length":
                length = int(value)
        out.append((int(top[9:12]), top, rest[:length]))
        data = rest[length:]
    return out


def spin(loop: asyncio.AbstractEventLoop) -> None:
    """Rounds of the loop until nothing is ready to run (at most :data:`SPINS`)."""
    for _ in range(SPINS):
        loop.run_until_complete(asyncio.sleep(0))
        if not getattr(loop, "_ready", True):  # (asyncio's queue of callbacks due now)
            break


def fuzz_one_input(data: bytes) -> None:
    if not data:
        return
    load()
    loop, api, pool, errors = _state["loop"], _state["api"], _state["pool"], _state["errors"]
    api.engine = fresh_engine()
    errors.seen.clear()
    conn = pool()
    transport = MemoryTransport(loop, conn)
    loop.call_soon(conn.connection_made, transport)  # (as asyncio does: on its loop)
    spin(loop)
    step = data[0] or len(data)
    rest = data[1:]
    for at in range(0, len(rest), step):
        if transport.closed:
            break
        loop.call_soon(conn.data_received, rest[at : at + step])
        spin(loop)
    spin(loop)
    transport.close()  # what is under way is cancelled: a client gone
    spin(loop)
    assert not errors.seen, errors.seen
    assert b"Traceback" not in transport.out
    for status, top, body in answers(bytes(transport.out)):
        if status < 200:
            continue  # 100 Continue
        assert status < 500 or status == 503, (status, top, body[:500])
        if b"content-type: text/plain; version=" in top.lower():
            assert status == 200  # /metrics
        elif b"content-type: application/octet-stream" in top.lower():
            assert status == 200 and body.startswith(b"ERVB")  # a release: its bundle
        else:
            assert b"application/json" in top, (top, body[:500])
            json.loads(body)
    for _ in range(3):  # the engine runs on
        api.engine.emit(api.engine.tick())


def main() -> None:
    import atheris

    with atheris.instrument_imports(include=["edgerv"]):
        for module in ("edgerv.handler.api", "edgerv.handler.admission", "edgerv.core.handoff"):
            importlib.import_module(module)
    load()
    atheris.Setup(sys.argv, fuzz_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
