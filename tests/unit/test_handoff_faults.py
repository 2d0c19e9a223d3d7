"""Fault injection between `edgerv migrate` and both handlers' APIs (issue 13's acceptance).

Two engines behind their real HTTP APIs, fed the same stream by a thread (as the `Pair` of
kit/handoff_pair.py), and a reference engine fed it too, with no handoff. The driver talks
to each API through a `FaultyGate`: a TCP forwarder that reads whole HTTP messages and, per
request, draws its fate from the seed's `random.Random`:

* pass;
* drop the request (close the client's connection: nothing reaches the handler);
* drop the answer (the handler acts; the driver never hears);
* delay the request or the answer by up to 1.5 driver call timeouts (a request the driver
  gave up on still lands later, as TCP delivers data ahead of the FIN);
* duplicate the request on a second upstream connection, either first (its answer thrown
  away: the driver sees the second one, as after its own retry) or late, up to 1.5 call
  timeouts after (a stale copy landing after the driver moved on);
* start a partition of this gate or both: every message, either way or answers only, is
  held until it heals (then delivered, or with probability 0.3 lost with its connection),
  0.5 to 2.5 driver timeouts later, so it often heals after the driver's deadline.
  A partition also starts, at random, right after the release (`after_release`).

Per seed: random batches of monitors moved edge -> cloud and back with the faults on, each
followed as a user would by running the same command again with the faults off (once the
partition healed, while stale messages may still land) until it is no longer unsettled;
sometimes an impatient user first moves the monitors back from where they report active.
What a handler still holds released with no driver is settled as `edgerv orchestrate`
does at the start of a round (`settle`). Between moves the handlers' own expiry of a
driverless handoff (HANDOFF_EXPIRES) is applied at random, deterministically
(`handoff_since` set back, `tick()`); at the end always, once nothing is in flight any
more. Checked:

1. never two active copies: a sampler thread, and a check after every call;
2. at the end, after the feeder stopped and all engines drained, the verdicts (verdict,
   step, stamp) of both handlers together equal the reference's: no event lost or doubled;
3. after settling, no monitor in a handoff state, and exactly one active copy.

The seeds fix the draws; the threads' timing varies, so a failing seed prints its schedule.
What it found is pinned by the deterministic tests at the end.
"""

from __future__ import annotations

import contextlib
import random
import socket
import threading
import time
from collections import Counter
from collections.abc import Callable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import ApiError, HandlerClient
from edgerv.control.migrate import (
    MigrationFailed,
    NotMoved,
    Unsettled,
    migrate,
    settle,
)
from edgerv.control.wire import HANDOFF_EXPIRES
from edgerv.core.monitor import CompiledMonitor
from edgerv.core.pipeline import Verdict
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from kit.counts import scaled
from kit.documents import compiled
from kit.engines import ManualClock
from kit.handoff_pair import TOKEN, Pair

TIMEOUT = 0.25  # the driver's --timeout under faults (its calls time out after as long)
GRACE = 0.2
SETTLE_TIMEOUT = 5.0  # the reruns, faults off
SEEDS = scaled(20)  # 40 before stop 35; make fuzz runs $EDGERV_PROPERTY_EXAMPLES
CONCURRENT = 20  # seeds run at once (each mostly waits: timeouts, partitions)
NAMES = ("m", "p")
ROOM = {"bufferCapacity": 1_000_000}  # held events never overflow during a long partition


def monitors() -> list[CompiledMonitor]:
    # m: a verdict (violated, then reset) every few steps, so a lost or doubled event
    # shifts the step of every later one; p: an obligation that spans many steps
    return [
        compiled("always (a -> x < 5)", {"a": "bool", "x": "float"}, name="m", **ROOM),
        compiled(
            "always (b -> (c until (x > 3)))",
            {"b": "bool", "c": "bool", "x": "float"},
            name="p",
            **ROOM,
        ),
    ]


# -- the network ---------------------------------------------------------------------------


class Net:
    """The faults of one seed, shared by its two gates: draws, partitions, what is in flight."""

    def __init__(self, seed: int) -> None:
        self.rng = random.Random(seed)
        self.lock = threading.Condition()
        self.faulty = False
        self.healed_at: dict[str, float] = {}  # gate -> when its partition heals
        self.mute: dict[str, bool] = {}  # gate -> its partition holds only the answers
        self.inflight = 0  # messages a gate holds (read, not yet delivered or lost)
        self.log: list[str] = []
        self.started = time.monotonic()

    def note(self, what: str) -> None:
        self.log.append(f"{time.monotonic() - self.started:7.3f} {what}")

    def draw(self, gate: str, path: str) -> tuple[str, float]:
        """A request's fate, and a delay (seconds) where it has one."""
        with self.lock:
            if not self.faulty:
                return "pass", 0.0
            r, delay = self.rng.random(), self.rng.uniform(0.0, 1.5 * TIMEOUT)
            fate = (
                "pass" if r < 0.76
                else "drop-request" if r < 0.79
                else "drop-answer" if r < 0.82
                else "delay-request" if r < 0.86
                else "delay-answer" if r < 0.89
                else "dup-first" if r < 0.93
                else "dup-late" if r < 0.97
                else "partition"
            )  # fmt: skip
            if fate == "partition":
                self._partition(gate, self.rng.random() < 0.5, self.rng.random() < 0.3)
            if fate != "pass":
                timed = fate.startswith("delay") or fate == "dup-late"
                self.note(f"{gate} {path}: {fate}" + (f" {delay:.2f}s" if timed else ""))
            return fate, delay

    def partition(self, gate: str, both: bool, mute: bool) -> None:
        with self.lock:
            self._partition(gate, both, mute)

    def _partition(self, gate: str, both: bool, mute: bool) -> None:
        length = self.rng.uniform(0.5, 2.5) * TIMEOUT
        until = time.monotonic() + length
        for g in ("edge", "cloud") if both else (gate,):
            self.healed_at[g] = max(self.healed_at.get(g, 0.0), until)
            self.mute[g] = mute
        self.note(
            f"partition of {'both' if both else gate} for {length:.2f}s"
            + (" (answers only)" if mute else "")
        )

    def hold(self, gate: str, answer: bool) -> bool:
        """Wait while a partition holds this message; False: it is lost with its connection."""
        with self.lock:
            held = False
            while True:
                left = self.healed_at.get(gate, 0.0) - time.monotonic()
                if left <= 0 or (not answer and self.mute.get(gate)):
                    break
                held = True
                self.lock.wait(left)
            return not held or self.rng.random() >= 0.3

    def dropped_ok(self, gate: str) -> None:
        """A 200 answer the gate dropped (fate ``drop-ok-answer``)."""

    def healed(self) -> None:
        """Wait until every partition healed."""
        with self.lock:
            while (left := max(self.healed_at.values(), default=0.0) - time.monotonic()) > 0:
                self.lock.wait(left)

    def take(self) -> None:
        with self.lock:
            self.inflight += 1

    def done(self) -> None:
        with self.lock:
            self.inflight -= 1
            self.lock.notify_all()

    @contextlib.contextmanager
    def carrying(self) -> Iterator[None]:
        self.take()
        try:
            yield
        finally:
            self.done()

    def quiet(self, timeout: float = 15.0) -> None:
        """Wait until no message is held or delayed anywhere (every stale one landed)."""
        self.healed()
        until = time.monotonic() + timeout
        with self.lock:
            while self.inflight:
                assert time.monotonic() < until, "messages stuck in the gates"
                self.lock.wait(0.05)


class Conn:
    """One side of a forwarded connection, read one HTTP message at a time."""

    def __init__(self, sock: socket.socket) -> None:
        self.sock, self.buf = sock, b""

    def message(self) -> bytes | None:
        """The next whole message (headers and Content-Length body), None at EOF."""
        while b"\r\n\r\n" not in self.buf:
            data = self.sock.recv(65536)
            if not data:
                return None
            self.buf += data
        head, _, _ = self.buf.partition(b"\r\n\r\n")
        length = 0
        for line in head.split(b"\r\n")[1:]:
            key, _, value = line.partition(b":")
            key = key.strip().lower()
            assert key != b"transfer-encoding", "the gate reads Content-Length bodies only"
            if key == b"content-length":
                length = int(value)
        size = len(head) + 4 + length
        while len(self.buf) < size:
            data = self.sock.recv(65536)
            if not data:
                return None
            self.buf += data
        message, self.buf = self.buf[:size], self.buf[size:]
        return message

    def ask(self, request: bytes) -> bytes | None:
        self.sock.sendall(request)
        return self.message()

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self.sock.close()


class FaultyGate:
    """A TCP forwarder to ``port`` that applies :meth:`Net.draw` to each request."""

    def __init__(self, net: Net, name: str, port: int) -> None:
        self.net, self.name, self.target = net, name, port
        self.server = socket.create_server(("127.0.0.1", 0))
        self.port = self.server.getsockname()[1]
        self.conns: list[Conn] = []
        threading.Thread(target=self._accept, daemon=True).start()

    def address(self) -> str:
        return f"127.0.0.1:{self.port}"

    def _upstream(self) -> Conn:
        conn = Conn(socket.create_connection(("127.0.0.1", self.target)))
        self.conns.append(conn)
        return conn

    def _accept(self) -> None:
        while True:
            try:
                sock, _ = self.server.accept()
            except OSError:
                return
            client = Conn(sock)
            self.conns.append(client)
            threading.Thread(target=self._serve, args=(client,), daemon=True).start()

    def _serve(self, client: Conn) -> None:
        upstream: Conn | None = None
        try:
            while (request := client.message()) is not None:
                with self.net.carrying():
                    path = request.split(b" ", 2)[1].decode()
                    fate, delay = self.net.draw(self.name, path)
                    if fate == "drop-request":
                        return
                    if fate == "delay-request":
                        time.sleep(delay)
                    if fate == "dup-first":
                        extra = self._upstream()
                        extra.ask(request)  # done, its answer thrown away
                        extra.close()
                    if fate == "dup-late":
                        self.net.take()  # (counted before its thread starts: see quiet)
                        threading.Thread(
                            target=self._late_copy, args=(request, delay), daemon=True
                        ).start()
                    if not self.net.hold(self.name, answer=False):
                        return
                    upstream = upstream or self._upstream()
                    answer = upstream.ask(request)
                    if answer is None or fate == "drop-answer":
                        return
                    if fate == "drop-ok-answer" and answer.startswith(b"HTTP/1.1 200"):
                        self.net.dropped_ok(self.name)
                        return
                    if fate == "delay-answer":
                        time.sleep(delay)
                    if not self.net.hold(self.name, answer=True):
                        return
                    client.sock.sendall(answer)
        except OSError:
            pass  # the driver gave up on this connection (its timeout), or the test ended
        finally:
            client.close()
            if upstream is not None:
                upstream.close()

    def _late_copy(self, request: bytes, delay: float) -> None:
        try:
            time.sleep(delay)
            if self.net.hold(self.name, answer=False):
                extra = self._upstream()
                extra.ask(request)
                extra.close()
        except OSError:
            pass
        finally:
            self.net.done()

    def close(self) -> None:
        self.server.close()
        for conn in self.conns:
            conn.close()


# -- the handlers --------------------------------------------------------------------------


class Sink:
    def __init__(self) -> None:
        self.got: list[tuple[str, str, int, int]] = []

    def write(self, handler: str, verdicts: Sequence[Verdict]) -> None:
        self.got += [(v.monitor, v.verdict, v.step, v.stamp) for v in verdicts]


class Sampler:
    """Reads, for each monitor, the active flag of the receiver of its latest move first,
    then the sender's. Within one move (and the reruns that settle it) a receiver that
    runs the monitor goes on running it: nothing else moves it away meanwhile, and every
    stale call of an older handoff is fenced by its epoch. So a receiver seen active at
    the first read is still active at the second, and a sender seen active then makes two
    copies at that instant: any (True, True) is a real violation. (The other order could
    see the sender just before its release and the receiver just after its adoption.)"""

    def __init__(self, engines: dict[str, Engine]) -> None:
        self.engines = engines
        self.order = {n: ("cloud", "edge") for n in NAMES}
        self.lock = threading.Lock()
        self.violations: list[str] = []
        self.samples = 0
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)
        self.thread.start()

    def moving(self, names: Sequence[str], receiver: str, sender: str) -> None:
        with self.lock:
            for n in names:
                self.order[n] = (receiver, sender)

    def _active(self, engine: str, name: str) -> bool:
        e = self.engines[engine]
        with e.lock:
            return e.slots[name].active

    def _run(self) -> None:
        while not self.stop.is_set():
            with self.lock:
                for name, (first, second) in self.order.items():
                    if self._active(first, name) and self._active(second, name):
                        self.violations.append(f"{name} active on {first} and {second}")
                self.samples += 1
            time.sleep(0.004)


class World:
    """Edge, cloud and a reference engine, fed one stream; the APIs behind their gates."""

    def __init__(self, seed: int) -> None:
        self.net = Net(seed)
        self.sinks = {n: Sink() for n in ("edge", "cloud", "reference")}
        self.clock = ManualClock(running=True)  # the handlers' clock: expire moves it on
        self.engines = {
            n: Engine(n, [self.sinks[n]], flush_after=1e9, clock=self.clock) for n in self.sinks
        }
        for m in monitors():
            for n, e in self.engines.items():
                e.put(m, active=n != "cloud")
        self.apis: list[ControlApi] = []
        self.gates: dict[str, FaultyGate] = {}
        for n in ("edge", "cloud"):
            api = ControlApi(self.engines[n], CollectorRegistry(), TOKEN, on_change=lambda: None)
            api.start("127.0.0.1", 0)
            self.apis.append(api)
            self.gates[n] = FaultyGate(self.net, n, api.port)
        self.sampler = Sampler(self.engines)
        self.outcomes: Counter[str] = Counter()  # what the driver said, by kind
        self.stopped = threading.Event()
        self.fed = 0
        self.feeder = threading.Thread(target=self._feed, daemon=True)
        self.feeder.start()

    def _feed(self) -> None:
        """Every topic in each batch, stamps increasing; a tick of each engine every
        few batches (evaluation and verdicts, as its scheduler would)."""
        i = 0
        while not self.stopped.is_set():
            i += 1
            s = i * 1_000_000
            batch = [
                (s, "/a", [i % 5 != 0]),
                (s + 1, "/b", [i % 3 == 0]),
                (s + 2, "/c", [i % 4 != 1]),
                (s + 3, "/x", [float(i % 7)]),
            ]
            for e in self.engines.values():
                e.ingest(batch)
            if i % 4 == 0:
                for e in self.engines.values():
                    e.emit(e.tick())
            self.fed = i
            time.sleep(0.005)

    def handler(self, name: str) -> HandlerClient:
        return HandlerClient(self.gates[name].address(), TOKEN)

    def where(self, name: str) -> list[str]:
        running = []
        for n in ("edge", "cloud"):
            with self.engines[n].lock:
                if self.engines[n].slots[name].active:
                    running.append(n)
        return running

    def check(self) -> None:
        for name in NAMES:
            assert len(self.where(name)) <= 1, f"{name} active on both handlers"

    def states(self, engine: str, names: Sequence[str]) -> dict[str, tuple[str | None, bool]]:
        """Each monitor's handoff state there, and whether it runs there (evaluated)."""
        e = self.engines[engine]
        with e.lock:
            return {n: (e.slots[n].handoff, e.slots[n].runtime is not None) for n in names}

    def told(
        self,
        src: str,
        dst: str,
        where: dict[str, str | None],
        before: dict[str, tuple[str | None, bool]],
    ) -> None:
        """What the driver said is so, right after it said it: moved -> the receiver runs
        the monitor; stays on the sender -> the sender runs it again (not held: the old
        false "stays"); on neither -> neither runs it; None -> the sender is as before.
        (Nothing moves them meanwhile: every stale call is fenced by its epoch.)"""
        runs = {
            self.handler(e).base: {n for n, (h, rt) in self.states(e, where).items()
                                   if h is None and rt}
            for e in (src, dst)
        }  # fmt: skip
        for name, place in where.items():
            if place is None:
                assert self.states(src, [name])[name] == before[name], f"{name} changed on {src}"
                continue
            holders = sorted(base for base, names in runs.items() if name in names)
            assert holders == ([place] if place else []), (
                f"{name}: the driver said {place or 'neither'}, it runs on {holders}"
            )

    def expire(self) -> list[str]:
        """What the handlers' own timer does to a handoff with no next step for
        HANDOFF_EXPIRES seconds (sending: resumes; receiving: lets go), without the wait."""
        undone = []
        self.clock.advance(HANDOFF_EXPIRES + 1)
        for e in (self.engines["edge"], self.engines["cloud"]):
            with e.lock:
                for slot in e.slots.values():
                    if slot.handoff in ("sending", "receiving"):
                        undone.append(f"{slot.name} {slot.handoff} on {e.name}")
                e.emit(e.tick())
        if undone:
            self.net.note(f"expired: {', '.join(undone)}")
        return undone

    def close(self) -> None:
        self.stopped.set()
        self.sampler.stop.set()
        self.feeder.join()
        self.sampler.thread.join()
        for g in self.gates.values():
            g.close()
        for api in self.apis:
            api.stop()


def move(world: World, src: str, dst: str, names: list[str], timeout: float) -> str:
    """One `edgerv migrate` run; what it said, checked against where the monitors run."""
    world.sampler.moving(names, dst, src)
    after: Callable[[], None] | None = None
    net = world.net
    if net.faulty and net.rng.random() < 0.4:  # the partition right after the release

        def after() -> None:
            net.partition(dst, net.rng.random() < 0.5, net.rng.random() < 0.5)

    before = world.states(src, names)
    try:
        migrate(world.handler(src), world.handler(dst), names, timeout, GRACE, after)
        outcome, where = "moved", dict.fromkeys(names, world.handler(dst).base)
    except Unsettled:
        outcome, where = "unsettled", {}
    except NotMoved as exc:
        outcome, where = f"not moved ({str(exc)[:100]})", exc.where
    except ApiError as exc:
        raise AssertionError(f"a failure that does not say where they run: {exc}") from None
    net.note(f"{'faulty' if net.faulty else 'clean'} {src}->{dst} {names}: {outcome}")
    world.told(src, dst, where, before)
    world.outcomes[outcome.split(" (")[0]] += 1
    world.check()
    return outcome


def rerun(world: World, src: str, dst: str, names: list[str], unsettled: bool) -> None:
    """Run the same command again, faults off, until it is no longer unsettled: after an
    unsettled move, the first rerun settles it (finishes or undoes it)."""
    for attempt in range(4):
        outcome = move(world, src, dst, names, SETTLE_TIMEOUT)
        if not outcome.startswith("unsettled"):
            return
        assert not (unsettled and attempt == 0), f"{src}->{dst} {names}: the rerun did not settle"
        time.sleep(0.1)
    raise AssertionError(f"{src}->{dst} {names} still unsettled with no faults")


def settle_held(world: World) -> None:
    """What `edgerv orchestrate` does at the start of each round: settle the monitors a
    handler holds released (its receiver says which it adopted), faults off."""
    for src, dst in (("edge", "cloud"), ("cloud", "edge")):
        held = [n for n in NAMES if world.engines[src].slots[n].handoff == "released"]
        if held:
            world.sampler.moving(held, dst, src)
            moved = settle(world.handler(src), held, time.monotonic() + SETTLE_TIMEOUT)
            world.net.note(f"settled {held} held on {src}: {moved or 'resumed'}")
            world.check()


def scenario(world: World, seed: int) -> None:
    rng, net = random.Random(seed * 7919 + 1), world.net
    for _ in range(rng.randint(3, 5)):
        # a batch of the monitors one handler runs, to the other
        runs = {e: [n for n in NAMES if world.where(n) == [e]] for e in ("edge", "cloud")}
        if not any(runs.values()):
            # Held released, active nowhere, though the driver said it failed (a release
            # that landed after it gave up, its abort lost): the next round of
            # `edgerv orchestrate`, or a rerun of the command, settles them.
            settle_held(world)
            continue
        src = rng.choice([e for e, here in runs.items() if here])
        dst = "cloud" if src == "edge" else "edge"
        names = rng.sample(runs[src], rng.randint(1, len(runs[src])))
        time.sleep(rng.uniform(0.0, 0.05))
        net.faulty = True
        outcome = move(world, src, dst, names, TIMEOUT)
        net.faulty = False
        if outcome == "unsettled" or (outcome != "moved" and rng.random() < 0.5):
            net.healed()  # the user runs it again once the link is back
            if outcome == "unsettled" and rng.random() < 0.5:
                # an impatient user first moves them back from where they run
                back = [n for n in names if world.where(n) == [dst]]
                if back:
                    move(world, dst, src, back, SETTLE_TIMEOUT)
            rerun(world, src, dst, names, outcome == "unsettled")
        if rng.random() < 0.3:
            world.expire()  # two minutes pass with no driver
    while world.fed < 100:  # enough events for verdicts
        time.sleep(0.01)
    for _ in range(2):
        net.quiet()  # every stale message landed
        world.expire()
        settle_held(world)
    for name in NAMES:
        states = {e: world.engines[e].slots[name].handoff for e in ("edge", "cloud")}
        assert states == {"edge": None, "cloud": None}, f"{name} left in a handoff: {states}"
        assert len(world.where(name)) == 1, f"{name} active on {world.where(name)}"


def compare(world: World) -> None:
    assert not world.sampler.violations, world.sampler.violations[:5]
    reference = world.sinks["reference"].got
    both = world.sinks["edge"].got + world.sinks["cloud"].got
    for name in NAMES:
        want = [v[1:] for v in reference if v[0] == name]
        got = sorted((v[1:] for v in both if v[0] == name), key=lambda v: v[1])
        assert got == want, f"{name}: {len(got)} verdicts, the reference {len(want)}"
    assert len(reference) > 20, f"only {len(reference)} verdicts"
    for e in world.engines.values():
        assert all(slot.dropped == 0 for slot in e.slots.values())


def run_seed(seed: int) -> tuple[str | None, Counter[str]]:
    """None, or what failed, with the seed's schedule; and the driver's outcomes."""
    world = World(seed)
    try:
        try:
            scenario(world, seed)
        finally:
            world.close()
        for e in world.engines.values():
            e.drain()
        compare(world)
        return None, world.outcomes
    except Exception as exc:
        log = "\n    ".join(world.net.log)
        return f"seed {seed}: {type(exc).__name__}: {exc}\n    {log}", world.outcomes


def test_faults_never_make_two_copies_nor_lose_or_double_an_event() -> None:
    with ThreadPoolExecutor(CONCURRENT) as pool:
        runs = list(pool.map(run_seed, range(SEEDS)))
    failures = [f for f, _ in runs if f]
    assert not failures, "\n".join(failures)
    said = sum((outcomes for _, outcomes in runs), Counter[str]())
    # every kind of outcome was said, and checked against the handlers, in these seeds
    assert {"moved", "not moved", "unsettled"} <= set(said), said
    print(said)


# -- what the faults found: a settle that asked a receiver which had moved on since --------


def test_a_settle_after_the_receiver_moved_the_monitor_on_commits_the_sender(
    pair: Pair,  # the fixture of conftest.py
) -> None:
    """What the fault test found (seeds 22 and 45 of a run before the fix), minimized: the
    adoption's answer is lost (unsettled: the cloud runs the monitor, the edge holds it
    released); the user moves it back from where it runs, which fails (the edge still
    holds it) and leaves the cloud running it under a newer epoch; then the first
    command, run again, settles the first handoff. The cloud answered `nothing to undo`
    for the handoff it had adopted, so the edge resumed: two copies. It now answers
    `active` (adopted, runs here)."""
    edge, cloud = pair.source(), pair.destination()  # the cloud through the gate

    def partition() -> None:
        pair.gate.mode = "mute"

    with pytest.raises(Unsettled):
        migrate(edge, cloud, ["m"], 0.3, 0.2, after_release=partition)
    pair.gate.mode = "pass"
    with pytest.raises(NotMoved, match=r"is held here, released to .* not yet settled") as back:
        migrate(cloud, edge, ["m"], 5.0, 0.5)  # back from where it runs
    assert back.value.where == {"m": cloud.base}  # (it said "already runs here" on the edge)
    assert pair.active() == ["cloud"] and pair.edge.slots["m"].handoff == "released"
    with contextlib.suppress(MigrationFailed):  # (so that the copies are checked first)
        moved = migrate(edge, cloud, ["m"], 5.0, 0.5)  # the first command again
    assert pair.active() == ["cloud"]
    assert "settle" in moved.steps and pair.edge.slots["m"].handoff is None


def test_a_settle_after_the_monitor_moved_on_to_a_third_handler_commits_the_sender(
    pair: Pair,  # the fixture of conftest.py
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """As above, but the cloud moved it on to a third handler (successfully): asked about
    the first handoff, it says it adopted it; the edge lets go; one copy, on the third."""
    edge, cloud = pair.source(), pair.destination()
    fog = Engine("fog", flush_after=1e9)
    fog.put(pair.edge.slots["m"].compiled, active=False)
    api = ControlApi(fog, CollectorRegistry(), TOKEN, on_change=lambda: None)
    api.start("127.0.0.1", 0)
    try:

        def partition() -> None:
            pair.gate.mode = "mute"

        with pytest.raises(Unsettled):
            migrate(edge, cloud, ["m"], 0.3, 0.2, after_release=partition)
        pair.gate.mode = "pass"
        heard = pair.cloud.ingest

        def both(batch: Any, *args: Any, **kwargs: Any) -> bool:
            fog.ingest(batch)  # the fog hears the robot too
            return heard(batch, *args, **kwargs)

        monkeypatch.setattr(pair.cloud, "ingest", both)
        migrate(cloud, HandlerClient(f"127.0.0.1:{api.port}", TOKEN), ["m"], 5.0, 0.2)
        assert fog.slots["m"].active and pair.active() == []
        with pytest.raises(MigrationFailed, match="which moved them on since"):
            migrate(edge, cloud, ["m"], 5.0, 0.5)  # the first command again
        assert pair.active() == [] and fog.slots["m"].active
        assert pair.edge.slots["m"].handoff is None and pair.edge.slots["m"].runtime is None
    finally:
        api.stop()


class Late(Net):
    """Delays every request to ``path`` past the driver's call timeout; passes the rest."""

    def __init__(self, path: str) -> None:
        super().__init__(0)
        self.path = path

    def draw(self, gate: str, path: str) -> tuple[str, float]:
        return ("delay-request", 0.4) if path.startswith(self.path) else ("pass", 0.0)


@pytest.mark.parametrize("step", ["hold", "receive"])
def test_a_hold_or_receive_that_lands_after_the_abort_is_fenced(
    pair: Pair,  # the fixture of conftest.py
    step: str,
) -> None:
    """The driver gave up on a late hold (or receive) and aborted both sides; the abort
    overtook it. The late call held the monitor for HANDOFF_EXPIRES (120 s): on the
    sender, `sending`, its events piling up unevaluated (`edgerv orchestrate` settles
    only `released` ones); on the receiver, `receiving`, every move to it refused. The
    abort of an epoch newer than any the handler saw now fences that epoch."""
    net = Late(f"/v1/handoff/{step}")
    gates = [FaultyGate(net, n, pair.apis[i].port) for i, n in enumerate(("edge", "cloud"))]
    edge, cloud = (HandlerClient(g.address(), TOKEN) for g in gates)
    try:
        with pytest.raises(MigrationFailed, match="timed out"):
            migrate(edge, cloud, ["m"], 0.25, 0.2)
        net.quiet()  # the late call landed
        assert pair.active() == ["edge"]
        assert [pair.edge.slots["m"].handoff, pair.cloud.slots["m"].handoff] == [None, None]
        migrate(edge, cloud, ["m"], 5.0, 0.2)  # the next move goes through
        assert pair.active() == ["cloud"]
    finally:
        for g in gates:
            g.close()


def test_an_abort_that_overtook_its_hold_or_receive_fences_them() -> None:
    from edgerv.core.handoff import HandoffError

    mon = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge, cloud = Engine("edge"), Engine("cloud")
    edge.put(mon, active=True)
    cloud.put(mon, active=False)
    for e in (edge, cloud):
        assert e.handoffs.abort("m", 5) == "nothing to undo"
    with pytest.raises(HandoffError, match="not newer"):
        edge.handoffs.hold("m", 5)
    with pytest.raises(HandoffError, match="not newer"):
        cloud.handoffs.receive("m", 5)
    edge.handoffs.hold("m", 6)  # a later handoff goes on
    assert edge.handoffs.abort("m", 7) == "nothing to undo"  # (in a handoff: nothing fenced)
    assert edge.slots["m"].epoch == 6 and edge.handoffs.abort("m", 6) == "resumed"


def test_a_receiver_answers_for_an_older_handoff_from_its_record_of_adoptions(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    import edgerv.handler.handoff_steps as handoff_steps

    monkeypatch.setattr(handoff_steps, "ADOPTIONS_KEPT", 2)
    mon = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge, cloud = Engine("edge", flush_after=1e9), Engine("cloud", flush_after=1e9)
    edge.put(mon, active=True)
    cloud.put(mon, active=False)
    stamp = 0

    def feed() -> None:
        nonlocal stamp
        for _ in range(2):
            stamp += 10
            for e in (edge, cloud):
                e.ingest([(stamp, "/a", [True]), (stamp + 1, "/x", [1.0])])

    def handoff(src: Engine, dst: Engine, epoch: int) -> None:
        src.handoffs.hold("m", epoch)
        dst.handoffs.receive("m", epoch)
        feed()
        cut = dst.handoffs.cut("m", epoch)
        assert cut is not None
        feed()
        snap = src.handoffs.release("m", epoch, cut, grace=0.0, now=0.0)
        assert snap is not None
        dst.handoffs.adopt("m", epoch, snap)
        src.handoffs.commit("m", epoch)

    cloud.handoffs.receive("m", 1)  # a handoff it never adopted (dropped)
    assert cloud.handoffs.abort("m", 1) == "dropped"
    handoff(edge, cloud, 2)
    assert cloud.handoffs.abort("m", 1) == "nothing to undo"
    cloud.handoffs.hold("m", 3)  # a newer handoff from the cloud, then undone: it runs there again
    assert cloud.handoffs.abort("m", 2) == "adopted"
    assert cloud.handoffs.abort("m", 3) == "resumed"
    assert cloud.handoffs.abort("m", 2) == "active"  # adopted then, runs here now
    assert cloud.handoffs.abort("m", 1) == "nothing to undo"  # never adopted: never will (fenced)
    handoff(cloud, edge, 4)
    assert cloud.handoffs.abort("m", 2) == "adopted"  # and moved on since
    handoff(edge, cloud, 5)
    handoff(cloud, edge, 6)
    handoff(edge, cloud, 7)  # the cloud adopted 2, 5, 7 and keeps the last two
    assert cloud.handoffs.abort("m", 5) == "active" and cloud.handoffs.abort("m", 7) == "active"
    assert (
        cloud.handoffs.abort("m", 2) == "unknown"
    )  # forgotten: the driver keeps the sender holding
    assert (
        cloud.handoffs.abort("m", 4) == "nothing to undo"
    )  # its record since 2 is whole: not adopted


class Cut(Net):
    """Passes everything until the ``gate`` answers a request to ``path`` with a 200 (the
    release that released: one that says "not yet, events past the cut to wait for" is
    passed, as a loaded machine answers it); drops that answer, and from then on every
    request to that gate (a partition that outlasts the driver), until ``heal``. A
    request to ``early`` is dropped even before: the driver sends it (its abort) once it
    gave up on the one to ``path``, on another connection, and a loaded machine's gate
    may read the later one first."""

    def __init__(self, gate: str, path: str, early: str = "/v1/handoff/abort") -> None:
        super().__init__(0)
        self.gate, self.path, self.early, self.cut = gate, path, early, False

    def draw(self, gate: str, path: str) -> tuple[str, float]:
        if gate != self.gate:
            return "pass", 0.0
        if not self.cut and path.startswith(self.path):
            return "drop-ok-answer", 0.0
        return ("drop-request" if self.cut or path.startswith(self.early) else "pass"), 0.0

    def dropped_ok(self, gate: str) -> None:
        with self.lock:
            self.cut = True

    def heal(self) -> None:
        self.gate = ""


class Lose(Net):
    """Drops every request to the paths given per gate, until ``heal``."""

    def __init__(self, paths: dict[str, str]) -> None:
        super().__init__(0)
        self.paths = paths

    def draw(self, gate: str, path: str) -> tuple[str, float]:
        lost = gate in self.paths and path.startswith(self.paths[gate])
        return ("drop-request" if lost else "pass"), 0.0

    def heal(self) -> None:
        self.paths = {}


@pytest.mark.parametrize(
    "net",
    [
        lambda: Cut("edge", "/v1/handoff/release"),  # its answer lost, then the edge's abort
        lambda: Lose({"cloud": "/v1/handoff/adopt", "edge": "/v1/handoff/abort"}),
    ],
    ids=["release-answer", "adoption"],
)
def test_a_sender_whose_abort_is_lost_is_unsettled_never_stays_and_the_rerun_settles(
    pair: Pair,  # the fixture of conftest.py
    net: Callable[[], Cut | Lose],
) -> None:
    """Issue 13's left-over: the edge released m, the driver did not get the snapshot (its
    answer lost) or the cloud's adoption was lost, and the abort to the edge was lost: the
    edge holds m released, evaluated nowhere. The driver said "m stays on the edge"
    (exit 1) after the first. Now: unsettled (exit 3), naming the edge as the handler it
    did not hear; the same command run again resumes m on the edge and moves it."""
    faults = net()
    gates = [FaultyGate(faults, n, pair.apis[i].port) for i, n in enumerate(("edge", "cloud"))]
    edge, cloud = (HandlerClient(g.address(), TOKEN) for g in gates)
    try:
        # 1 s: the hold, receive and cut must be answered in time on a loaded machine (the
        # driver would give up before its release); only the lost answers cost it
        with pytest.raises(Unsettled) as unsettled:
            migrate(edge, cloud, ["m"], 1.0, 0.2)
        assert unsettled.value.silent == [edge.base] and unsettled.value.names == ["m"]
        # The driver gives up on the release; under load the gate may read it later, and
        # the edge answer later still (the answer dropped): wait for it.
        until = time.monotonic() + 15
        while pair.edge.slots["m"].handoff != "released" and time.monotonic() < until:
            time.sleep(0.02)
        assert pair.edge.slots["m"].handoff == "released" and pair.active() == []
        faults.heal()
        moved = migrate(edge, cloud, ["m"], 5.0, 0.2)  # the same command again
        assert moved.letters > 0 and not moved.already  # resumed on the edge, moved afresh
        assert pair.active() == ["cloud"] and pair.edge.slots["m"].handoff is None
    finally:
        for g in gates:
            g.close()


def test_a_refused_hold_or_receive_says_what_the_monitor_does_there() -> None:
    """`already runs here` only where it runs: a monitor held for a handoff, released in
    one not yet settled, or being received is evaluated nowhere there."""
    from edgerv.core.handoff import HandoffError

    mon = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge, cloud = Engine("edge"), Engine("cloud")
    edge.put(mon, active=True)
    cloud.put(mon, active=False)
    with pytest.raises(HandoffError, match="'m' does not run here"):
        cloud.handoffs.hold("m", 1)
    with pytest.raises(HandoffError, match="'m' already runs here"):
        edge.handoffs.receive("m", 1)
    edge.handoffs.hold("m", 2, peer="http://cloud")
    cloud.handoffs.receive("m", 2)
    with pytest.raises(HandoffError, match=r"held here for a handoff to http://cloud \(epoch 2\)"):
        edge.handoffs.receive("m", 3)
    with pytest.raises(HandoffError, match=r"being received here in another handoff \(epoch 2\)"):
        cloud.handoffs.receive("m", 3)
    with pytest.raises(HandoffError, match="being received here"):
        cloud.handoffs.hold("m", 3)
    edge.ingest([(1, "/a", [True]), (2, "/x", [1.0])])
    assert edge.handoffs.release("m", 2, cut=0, grace=0.0, now=0.0) is not None
    with pytest.raises(HandoffError, match="released to http://cloud in a handoff not yet settled"):
        edge.handoffs.receive("m", 4)
    with pytest.raises(HandoffError, match=r"to http://cloud .*\(epoch 2\), not evaluated"):
        edge.handoffs.hold("m", 4)
