"""`edgerv migrate` over real HTTP between two handlers' APIs (engines fed directly, no ROS),
with a TCP gate in front of the receiver that can cut the link: the failures after the
release, where the driver cannot know whether the receiver adopted.

The invariant: at most one active copy of a monitor, whatever is lost; and running the
same migration again settles what a lost answer left held.
"""

from __future__ import annotations

import logging
import threading
import time

import pytest
import yaml

from edgerv.control.client import Conflict, HandlerClient
from edgerv.control.migrate import MigrationFailed, Unsettled, migrate
from edgerv.control.wire import HANDOFF_EXPIRES
from edgerv.handler.engine import Engine
from kit.documents import compiled, monitor_doc
from kit.engines import ManualClock
from kit.handoff_pair import TOKEN, Gate, Pair


def test_each_handler_records_the_handoffs_it_took_part_in(
    pair: Pair, caplog: pytest.LogCaptureFixture
) -> None:
    """Who moved what is read back from the handlers' logs, one line a step that changes
    who runs a monitor, under the handoff's epoch (two drivers would show two epochs)."""
    with caplog.at_level(logging.INFO, logger="edgerv.handler.api"):
        migrate(pair.source(), pair.destination(), ["m"], 5.0, 0.5)
    records = [r.getMessage() for r in caplog.records if r.getMessage().startswith("handoff ")]
    epochs = {line.split()[1] for line in records}
    assert len(epochs) == 1, records
    steps = [line.split(maxsplit=2)[2] for line in records]
    cloud = pair.destination().base
    assert steps == [f"held for {cloud}: m", "adopted: m", "committed: m"], records
    assert pair.active() == ["cloud"]


def test_an_adoption_whose_answer_is_lost_leaves_one_copy_and_settles(pair: Pair) -> None:
    def partition() -> None:
        pair.gate.mode = "mute"  # the adoption reaches the cloud; its answer does not come

    with pytest.raises(Unsettled, match="did not say whether it adopted m"):
        migrate(pair.source(), pair.destination(), ["m"], 0.5, 0.5, after_release=partition)
    assert pair.active() == ["cloud"]  # it adopted; the edge did not resume: one copy
    assert pair.edge.slots["m"].handoff == "released"
    pair.gate.mode = "pass"
    moved = migrate(pair.source(), pair.destination(), ["m"], 5.0, 0.5)  # the same command
    assert "settle" in moved.steps and pair.active() == ["cloud"]
    assert pair.edge.slots["m"].handoff is None and pair.edge.slots["m"].runtime is None


def test_a_monitor_held_by_a_handoff_is_not_redefined_until_it_is_settled(pair: Pair) -> None:
    """A definition in the middle of a handoff would restart the monitor there and lose
    the move: the handler refuses it (409) until the handoff is settled."""
    doc = yaml.safe_dump(monitor_doc("m", "always (a -> x < 5)", {"a": "bool", "x": "float"}))

    def partition() -> None:
        pair.gate.mode = "black"

    with pytest.raises(Unsettled):
        migrate(pair.source(), pair.destination(), ["m"], 0.5, 0.5, after_release=partition)
    with pytest.raises(Conflict, match="in a handoff \\(released\\): settle or abort it first"):
        pair.source().define("m", doc, active=True)
    pair.gate.mode = "pass"
    migrate(pair.source(), pair.destination(), ["m"], 5.0, 0.5)  # settles, then moves
    assert pair.active() == ["cloud"]
    assert pair.source().define("m", doc, active=False) is False  # settled: it may be
    assert pair.active() == ["cloud"]


def test_an_adoption_that_never_arrived_leaves_none_and_settles(pair: Pair) -> None:
    def partition() -> None:
        pair.gate.mode = "black"

    with pytest.raises(Unsettled):
        migrate(pair.source(), pair.destination(), ["m"], 0.5, 0.5, after_release=partition)
    assert pair.active() == []  # held on the edge, received on the cloud: active nowhere
    pair.gate.mode = "pass"
    moved = migrate(pair.source(), pair.destination(), ["m"], 5.0, 0.5)
    assert "settle" not in moved.steps and moved.letters > 0  # resumed, then moved afresh
    assert pair.active() == ["cloud"]


def test_a_receiver_that_is_down_after_the_release_lets_the_sender_resume(pair: Pair) -> None:
    destination = HandlerClient(f"127.0.0.1:{pair.apis[1].port}", TOKEN)  # no gate: refused

    with pytest.raises(MigrationFailed, match="down: the sender resumed") as failed:
        migrate(pair.source(), destination, ["m"], 0.5, 0.5, after_release=pair.apis[1].stop)
    assert not isinstance(failed.value, Unsettled)
    assert pair.active() == ["edge"] and pair.edge.slots["m"].handoff is None


def test_a_handoff_no_driver_finishes_is_undone_where_that_is_safe() -> None:
    clock = ManualClock()
    edge, cloud = Engine("edge", clock=clock), Engine("cloud", clock=clock)
    monitor = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge.put(monitor, active=True)
    cloud.put(monitor, active=False)
    edge.handoffs.hold("m", 1)
    cloud.handoffs.receive("m", 1)
    clock.advance(HANDOFF_EXPIRES - 1)
    for e in (edge, cloud):
        e.tick()
    assert edge.slots["m"].handoff == "sending" and cloud.slots["m"].handoff == "receiving"
    clock.advance(2)  # its driver died HANDOFF_EXPIRES + 1 s ago
    for e in (edge, cloud):
        e.tick()
    assert edge.slots["m"].active and edge.slots["m"].handoff is None  # resumed
    assert cloud.slots["m"].runtime is None and cloud.slots["m"].handoff is None  # dropped
    edge.handoffs.hold("m", 2)
    cloud.handoffs.receive("m", 2)
    edge.ingest([(1, "/a", [True]), (2, "/x", [1.0])])
    assert edge.handoffs.release("m", 2, cut=0, grace=0.0, now=0.0) is not None
    clock.advance(HANDOFF_EXPIRES + 1)
    edge.tick()
    assert edge.slots["m"].handoff == "released"  # the cloud may have adopted: not undone


class BadPeer:
    """A receiver that answers every request 200 with the same wrong body."""

    def __init__(self, body: bytes) -> None:
        import http.server

        answer = body

        class Answer(http.server.BaseHTTPRequestHandler):
            def do_POST(self) -> None:
                self.rfile.read(int(self.headers.get("Content-Length") or 0))
                self.send_response(200)
                self.send_header("Content-Length", str(len(answer)))
                self.end_headers()
                self.wfile.write(answer)

            do_GET = do_POST

            def log_message(self, *args: object) -> None:
                pass

        self.server = http.server.ThreadingHTTPServer(("127.0.0.1", 0), Answer)
        self.port = self.server.server_address[1]
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()


@pytest.mark.parametrize(
    "body",
    [b"{}", b"not json", b'{"cuts": "x", "ok": true}', b'{"cuts": {"m": "soon"}}',
     b'{"cuts": {"m": 5, "other": 7}}', b'{"cuts": {"m": 5}, "quiet": {"m": "/a"}}',
     b"[" * 50_000 + b"]" * 50_000],
)  # fmt: skip
def test_a_peer_that_answers_wrong_fails_the_move_and_the_monitor_resumes(
    pair: Pair, body: bytes
) -> None:
    """A buggy, old or hostile receiver: the driver says what was wrong and undoes the
    handoff; the monitor runs on the sender again, evaluated, not held."""
    peer = BadPeer(body)
    try:
        with pytest.raises(MigrationFailed) as failed:
            migrate(pair.source(), HandlerClient(f"127.0.0.1:{peer.port}", TOKEN), ["m"], 2.0, 0.5)
    finally:
        peer.close()
    assert "cut" in str(failed.value)
    assert not isinstance(failed.value, Unsettled)
    assert pair.edge.slots["m"].active and pair.edge.slots["m"].handoff is None


@pytest.mark.parametrize(
    ("path", "body"),
    [("/v1/monitors", b"spec: " + b"[" * 50_000 + b"]" * 50_000),
     ("/v1/monitors", b'{"spec": ' + b"[" * 50_000 + b"]" * 50_000 + b"}"),
     ("/v1/handoff/cut", b'{"epoch": 1, "monitors": ' + b"[" * 50_000 + b"]" * 50_000 + b"}")],
)  # fmt: skip
def test_a_request_nested_too_deep_gets_a_400_and_the_api_lives_on(
    pair: Pair, path: str, body: bytes
) -> None:
    import urllib.error
    import urllib.request

    url = f"http://127.0.0.1:{pair.apis[0].port}"
    request = urllib.request.Request(
        url + path, data=body, method="POST", headers={"Authorization": f"Bearer {TOKEN}"}
    )
    with pytest.raises(urllib.error.HTTPError) as answer:
        urllib.request.urlopen(request, timeout=10)
    assert answer.value.code == 400
    assert b"nested" in answer.value.read()
    listing = urllib.request.Request(
        url + "/v1/monitors", headers={"Authorization": f"Bearer {TOKEN}"}
    )
    with urllib.request.urlopen(listing, timeout=10) as ok:
        assert ok.status == 200  # still there


def cli(argv: list[str]) -> int:
    """`edgerv migrate ARGV` in this process (its exit code; stderr to capsys)."""
    import argparse

    from edgerv.control import migrate_command as command

    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    return command.run(parser.parse_args(argv))


def test_a_monitor_already_on_the_target_is_not_moved_and_that_is_no_failure(
    pair: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Asked again after it moved: the sender's hold and the receiver's receive are both
    refused. It used to say "m stays on EDGE: ... already runs here" (exit 1): m ran on
    the cloud, not on the edge."""
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge, cloud = pair.source().base, pair.destination().base
    argv = ["--from", edge, "--to", cloud, "--monitor", "m", "--timeout", "2"]
    assert cli(argv) == 0 and pair.active() == ["cloud"]
    assert "m runs on" in capsys.readouterr().err
    assert cli(argv) == 0 and pair.active() == ["cloud"]
    said = capsys.readouterr().err
    assert said == f"edgerv migrate: m ran on {cloud} already (nothing to move)\n"


def test_exit_3_says_the_move_is_unsettled_who_did_not_answer_and_what_to_run(
    pair: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The edge takes the hold, then hears nothing more (the abort is lost): it holds m,
    evaluated nowhere. Exit 3 (never "stays on the edge"), naming the edge and the
    command to run; that command, run again once the edge answers, finishes the job."""
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    gate = Gate(pair.apis[0].port)  # in front of the edge
    try:
        edge, cloud = f"http://127.0.0.1:{gate.port}", pair.destination().base
        argv = ["--from", edge, "--to", cloud, "--monitor", "m", "--timeout", "0.3"]
        gate.mode = "mute"

        def cut_once_held() -> None:  # then nothing reaches the edge: the abort is lost
            while pair.edge.slots["m"].handoff != "sending":
                time.sleep(0.001)
            gate.mode = "black"

        watcher = threading.Thread(target=cut_once_held, daemon=True)
        watcher.start()
        assert cli(argv) == 3
        watcher.join()
        err = capsys.readouterr().err
        assert err.startswith("edgerv migrate: m: unsettled: the move failed")
        assert f"{edge} did not confirm it resumed m" in err
        again = f"edgerv migrate --from {edge} --to {cloud} --monitor m --timeout 0.3"
        assert err.endswith(f"run `{again}` again once {edge} answer(s): "
                            "it finishes the move or undoes it\n")  # fmt: skip
        assert pair.edge.slots["m"].handoff == "sending" and not pair.cloud.slots["m"].active
        gate.mode = "pass"
        assert cli(argv) == 0
        assert pair.active() == ["cloud"] and pair.edge.slots["m"].handoff is None
    finally:
        gate.close()


def test_a_wrong_token_changes_nothing_and_says_so(
    pair: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Every call is refused (401), the abort and the listings too: nothing of the move
    took effect, which is what it says (exit 1), not that m stays or is unsettled."""
    monkeypatch.setenv("EDGERV_TOKEN", "wrong")
    edge, cloud = pair.source().base, pair.destination().base
    assert cli(["--from", edge, "--to", cloud, "--monitor", "m", "--timeout", "1"]) == 1
    said = capsys.readouterr().err
    assert said.startswith(
        f"edgerv migrate: not moved: m: nothing of this move took effect on {edge}"
    )
    assert "(HTTP 401)" in said and pair.active() == ["edge"] and pair.edge.slots["m"].epoch == 0


@pytest.mark.parametrize(("cut_off", "runs_on"), [("black", "edge"), ("mute", "cloud")])
def test_an_operator_that_restarts_mid_handoff_settles_it(
    pair: Pair, cut_off: str, runs_on: str
) -> None:
    """The operator's driver is gone after the release (cut off, then restarted): the new
    one's first survey finds the monitor held and settles it where it runs, one copy."""
    from edgerv.control.orchestrate import Orchestrator
    from edgerv.control.placement import PolicyConfig
    from edgerv_operator.config import OperatorConfig
    from edgerv_operator.documents import HandlerPod
    from edgerv_operator.handlers import Operator, settle_orphans

    def partition() -> None:
        pair.gate.mode = cut_off  # black: the adoption never arrives; mute: its answer

    with pytest.raises(Unsettled):
        migrate(pair.source(), pair.destination(), ["m"], 0.5, 0.5, after_release=partition)
    assert pair.edge.slots["m"].handoff == "released"
    pair.gate.mode = "pass"
    config = OperatorConfig("ns", "a=b", pair.apis[0].port, TOKEN, ("edge", "cloud"))
    op = Operator(config, Orchestrator([], PolicyConfig(tiers=config.tiers), TOKEN, starts=False))
    edge = HandlerPod("edge", "edge", f"127.0.0.1:{pair.apis[0].port}", "edge-pod")
    op.reports = {edge: {m["name"]: m for m in pair.source().monitors()}}
    settle_orphans(op, [edge])
    assert pair.active() == [runs_on]
    assert pair.edge.slots["m"].handoff is None and pair.cloud.slots["m"].handoff is None
    settle_orphans(op, [edge])  # stale reports: it lists afresh, nothing to do
    assert pair.active() == [runs_on]


def test_a_stopping_operator_ends_its_move_and_settles_what_it_left(pair: Pair) -> None:
    """Graceful shutdown (Kopf's cleanup): it waits for the move in progress (the moves'
    lock), keeps the lock so no other starts, and settles a handoff left held, asking the
    handlers afresh (its last survey predates it)."""
    import kopf

    from edgerv.control.orchestrate import Orchestrator
    from edgerv.control.placement import PolicyConfig
    from edgerv_operator.config import OperatorConfig
    from edgerv_operator.documents import HandlerPod
    from edgerv_operator.handlers import Operator, stopping

    def partition() -> None:
        pair.gate.mode = "black"

    with pytest.raises(Unsettled):
        migrate(pair.source(), pair.destination(), ["m"], 0.5, 0.5, after_release=partition)
    pair.gate.mode = "pass"
    config = OperatorConfig("ns", "a=b", pair.apis[0].port, TOKEN, ("edge", "cloud"))
    op = Operator(config, Orchestrator([], PolicyConfig(tiers=config.tiers), TOKEN, starts=False))
    op.reports = {HandlerPod("edge", "edge", f"127.0.0.1:{pair.apis[0].port}", "edge-pod"): {}}
    op.moving.acquire()  # a move in progress, ending in 0.5 s
    ended = threading.Event()

    def move() -> None:
        time.sleep(0.5)
        ended.set()
        op.moving.release()

    threading.Thread(target=move, daemon=True).start()
    memo = kopf.Memo()
    memo["edgerv"] = op
    stopping(memo=memo)
    assert ended.is_set() and op.moving.locked()  # it waited, and holds the lock
    assert pair.active() == ["edge"] and pair.edge.slots["m"].handoff is None
