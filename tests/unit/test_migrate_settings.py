"""`edgerv migrate` against handlers it cannot use as given (docs/handler.md, "Moving
monitors"): real handler APIs on real sockets, real TLS with certificates made by
``openssl`` (tests/kit/pki.py), engines fed directly (no ROS).

What is checked: a handler that speaks HTTPS called over plain HTTP, or the reverse, or
whose certificate is not trusted, or whose host is not known, ends the command with exit 1
and one line saying what to change, before anything is held: the monitor runs on the
source as before, as its API says. A handler that only goes away is still unreachable
(not a mismatch). The "run again" line of an unsettled move spells out the command with
every option given, and that very command, run again, finishes the move. Bad arguments
exit 2 at their flag; the help is plain text with the defaults.
"""

from __future__ import annotations

import contextlib
import shlex
import shutil
import socket
import threading
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest
from prometheus_client import CollectorRegistry

from edgerv.cli import main as cli_main
from edgerv.control.client import HandlerClient, Unreachable, WrongScheme
from edgerv.control.migrate import NotMoved, migrate
from edgerv.control.tls import ClientTls, server_context
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from kit.documents import compiled
from kit.engines import robot_feed
from kit.handoff_pair import TOKEN, Gate, edge_and_cloud
from kit.pki import NAME, Pki, shared_pki


@pytest.fixture(scope="module")
def pki() -> Pki:
    return shared_pki()


@dataclass
class Pair:
    """Two handlers' APIs on loopback, the edge running ``m``, the cloud defining it."""

    edge: Engine
    cloud: Engine
    apis: list[ControlApi]
    https: bool
    pki: Pki

    def address(self, i: int) -> str:
        return f"127.0.0.1:{self.apis[i].port}"

    def client(self, i: int) -> HandlerClient:
        """A client that reaches handler ``i`` as it serves (the truth, not the command's)."""
        if self.https:
            return HandlerClient(self.address(i), TOKEN, ClientTls(str(self.pki.ca), NAME))
        return HandlerClient(self.address(i), TOKEN)

    def listed(self, i: int) -> dict[str, object]:
        """``m`` as handler ``i``'s API lists it: whether it runs there, its handoff."""
        (m,) = [m for m in self.client(i).monitors() if m["name"] == "m"]
        return {"active": m["active"], "handoff": m["handoff"], "epoch": m["epoch"]}


def pair_of(pki: Pki, https: bool) -> Iterator[Pair]:
    edge, cloud = edge_and_cloud()
    apis = []
    for e in (edge, cloud):
        api = ControlApi(e, CollectorRegistry(), TOKEN, on_change=lambda: None)
        tls = server_context(str(pki.crt), str(pki.key)) if https else None
        api.start("127.0.0.1", 0, tls=tls)
        apis.append(api)
    try:
        with robot_feed([edge, cloud]):
            yield Pair(edge, cloud, apis, https, pki)
    finally:
        for api in apis:
            api.stop()


@pytest.fixture
def plain(pki: Pki) -> Iterator[Pair]:
    yield from pair_of(pki, https=False)


@pytest.fixture
def https(pki: Pki) -> Iterator[Pair]:
    yield from pair_of(pki, https=True)


def cli(argv: list[str]) -> int:
    """`edgerv migrate ARGV` as the command line runs it (its exit code; stderr to capsys)."""
    return cli_main(["migrate", *argv])


UNTOUCHED = {"active": True, "handoff": None, "epoch": 0}  # the edge: runs m, never held
IDLE = {"active": False, "handoff": None, "epoch": 0}  # the cloud: never received m


def test_plain_http_handlers_given_a_ca_say_so_and_nothing_is_held(
    plain: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge, cloud = plain.address(0), plain.address(1)
    code = cli(["--from", edge, "--to", cloud, "--monitor", "m", "--ca-file", str(plain.pki.ca)])
    err = capsys.readouterr().err
    assert code == 1, err
    assert err == (
        f"edgerv migrate: not moved: --from {edge} and --to {cloud} speak plain HTTP: drop "
        f"--ca-file, or use http://{edge} and http://{cloud}; nothing was held: m runs where "
        "it ran\n"
    )
    assert plain.listed(0) == UNTOUCHED and plain.listed(1) == IDLE
    # the hint, followed, moves it
    assert cli(["--from", f"http://{edge}", "--to", cloud, "--monitor", "m"]) == 0
    assert plain.listed(1)["active"] and not plain.listed(0)["active"]


def test_https_handlers_called_without_a_ca_say_so_and_nothing_is_held(
    https: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """Loopback addresses without --ca-file are called over plain HTTP: the handlers'
    TLS takes the request for a bad handshake. It used to end unsettled (exit 3, "held
    by --from and evaluated nowhere") after --timeout, its hint without the TLS options."""
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge, cloud = https.address(0), https.address(1)
    code = cli(["--from", edge, "--to", cloud, "--monitor", "m", "--timeout", "20"])
    err = capsys.readouterr().err
    assert code == 1, err
    assert err == (
        f"edgerv migrate: not moved: --from {edge} and --to {cloud} speak HTTPS: give "
        "--ca-file (the CA that signed their certificates); nothing was held: m runs "
        "where it ran\n"
    )
    assert https.listed(0) == UNTOUCHED and https.listed(1) == IDLE
    monkeypatch.delenv("EDGERV_TOKEN")  # the token is named too when it is missing
    assert cli(["--from", edge, "--to", f"http://{cloud}", "--monitor", "m"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(
        f"edgerv migrate: not moved: --from {edge} and --to http://{cloud} speak HTTPS: give "
        "--ca-file (the CA that signed their certificates) and their addresses without "
        "http://, and the token in EDGERV_TOKEN; nothing was held"
    ), err
    assert https.listed(0) == UNTOUCHED and https.listed(1) == IDLE


def test_one_handler_of_each_scheme_names_the_one_to_change(
    pki: Pki, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    """The edge serves HTTPS, the cloud plain HTTP: given the CA, only the cloud's address
    is to change, and the library's migrate (no check first: the orchestrator's) fails
    the same move as not moved, never unsettled: the hold never reached the edge's engine
    or the receive the cloud's."""
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge_engine, cloud_engine = Engine("edge", flush_after=1e9), Engine("cloud", flush_after=1e9)
    monitor = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge_engine.put(monitor, active=True)
    cloud_engine.put(monitor, active=False)
    edge_api = ControlApi(edge_engine, CollectorRegistry(), TOKEN, on_change=lambda: None)
    edge_api.start("127.0.0.1", 0, tls=server_context(str(pki.crt), str(pki.key)))
    cloud_api = ControlApi(cloud_engine, CollectorRegistry(), TOKEN, on_change=lambda: None)
    cloud_api.start("127.0.0.1", 0)
    try:
        edge, cloud = f"127.0.0.1:{edge_api.port}", f"127.0.0.1:{cloud_api.port}"
        argv = ["--from", edge, "--to", cloud, "--monitor", "m", "--ca-file", str(pki.ca)]
        assert cli(argv) == 1
        assert capsys.readouterr().err == (
            f"edgerv migrate: not moved: --to {cloud} speaks plain HTTP: drop --ca-file, or "
            f"use http://{cloud}; nothing was held: m runs where it ran\n"
        )
        assert edge_engine.slots["m"].active and edge_engine.slots["m"].epoch == 0
        tls = ClientTls(str(pki.ca))
        with pytest.raises(NotMoved, match="speaks plain HTTP, not HTTPS") as failed:
            migrate(HandlerClient(edge, TOKEN, tls), HandlerClient(cloud, TOKEN, tls), ["m"], 5.0)
        assert "did not confirm it let go" not in str(failed.value)  # it never received
        assert edge_engine.slots["m"].active and edge_engine.slots["m"].handoff is None
        assert cloud_engine.slots["m"].epoch == 0  # nothing reached it
        with pytest.raises(NotMoved, match="speaks HTTPS, not plain HTTP"):  # the other way
            migrate(HandlerClient(cloud, TOKEN), HandlerClient(edge, TOKEN), ["m"], 5.0)
        assert edge_engine.slots["m"].active and edge_engine.slots["m"].handoff is None
        assert cloud_engine.slots["m"].handoff is None and not cloud_engine.slots["m"].active
    finally:
        edge_api.stop()
        cloud_api.stop()


@pytest.mark.parametrize(
    ("ca", "name", "said"),
    [
        ("stranger", None, "check that --ca-file is the CA that signed it, and that this is "
         "the handler"),
        ("ca", "edgerv-handler.other.svc", "give --tls-server-name with the name it carries"),
    ],
)  # fmt: skip
def test_an_untrusted_certificate_says_which_option_to_change(
    https: Pair,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
    ca: str,
    name: str | None,
    said: str,
) -> None:
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge, cloud = https.address(0), https.address(1)
    argv = [
        "--from",
        edge,
        "--to",
        cloud,
        "--monitor",
        "m",
        "--ca-file",
        str(getattr(https.pki, ca)),
    ]
    argv += ["--tls-server-name", name] if name else []
    assert cli(argv) == 1
    err = capsys.readouterr().err
    assert err.startswith(
        f"edgerv migrate: not moved: --from {edge}: its certificate is not trusted ("
    )
    assert f"): {said}; --to {cloud}: its certificate is not trusted (" in err, err
    assert err.endswith("; nothing was held: m runs where it ran\n") and err.count("\n") == 1
    assert https.listed(0) == UNTOUCHED and https.listed(1) == IDLE


def test_a_host_that_is_not_known_is_said_before_anything_is_held(
    plain: Pair, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    edge = plain.address(0)
    assert cli(["--from", edge, "--to", "edgerv-cloud.invalid:8470", "--monitor", "m"]) == 1
    err = capsys.readouterr().err
    assert err.startswith(
        "edgerv migrate: not moved: --to edgerv-cloud.invalid:8470: its host "
        "edgerv-cloud.invalid is not known ("
    ), err
    assert err.endswith("); nothing was held: m runs where it ran\n")
    assert plain.listed(0) == UNTOUCHED


@contextlib.contextmanager
def closing_server() -> Iterator[int]:
    """A port that accepts connections and closes each at once: a handler going away."""
    server = socket.create_server(("127.0.0.1", 0))

    def serve() -> None:
        while True:
            try:
                conn, _ = server.accept()
            except OSError:
                return
            conn.close()

    threading.Thread(target=serve, daemon=True).start()
    try:
        yield server.getsockname()[1]
    finally:
        server.close()


def test_a_handler_that_only_goes_away_is_unreachable_not_a_mismatch(pki: Pki) -> None:
    """A closed connection is what a plain-HTTP call to an HTTPS handler gets, and a failed
    handshake what an HTTPS call to a plain one gets: each is a mismatch only when the
    other scheme, tried, answers."""
    with closing_server() as port:
        with pytest.raises(Unreachable):
            HandlerClient(f"127.0.0.1:{port}", TOKEN).monitors(timeout=2.0)
        with pytest.raises(Unreachable):
            HandlerClient(f"127.0.0.1:{port}", TOKEN, ClientTls(str(pki.ca))).monitors(timeout=2)


def test_the_mismatch_is_confirmed_in_the_other_scheme(https: Pair, plain: Pair) -> None:
    with pytest.raises(WrongScheme, match="speaks HTTPS, not plain HTTP") as over_http:
        HandlerClient(https.address(0), TOKEN).monitors()
    assert over_http.value.speaks == "https"
    with pytest.raises(WrongScheme, match="speaks plain HTTP, not HTTPS") as over_https:
        HandlerClient(plain.address(0), TOKEN, ClientTls(str(plain.pki.ca))).monitors()
    assert over_https.value.speaks == "http"
    # each reached as it serves: the same calls go through, and nothing changed
    assert https.listed(0) == UNTOUCHED and plain.listed(0) == UNTOUCHED


def test_the_rerun_line_of_an_unsettled_move_keeps_every_option_and_finishes_it(
    https: Pair,
    tmp_path: Path,
    capsys: pytest.CaptureFixture[str],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Over HTTPS, a gate in front of the edge lets no answer back: the edge never says
    whether it took the hold, so the move is unsettled (exit 3). The line to run again
    has every option as given (the CA in a directory with a space, quoted), and that
    very line, once the edge answers, moves the monitor."""
    monkeypatch.setenv("EDGERV_TOKEN", TOKEN)
    ca = tmp_path / "my certs" / "ca.crt"
    ca.parent.mkdir()
    shutil.copy(https.pki.ca, ca)
    gate = Gate(https.apis[0].port)
    try:
        gate.mode = "mute"  # the TLS handshakes to the edge never finish
        edge, cloud = f"127.0.0.1:{gate.port}", https.address(1)
        argv = ["--from", edge, "--to", cloud, "--monitor", "m", "--timeout", "0.4",
                "--grace", "0.25", "--ca-file", str(ca), "--tls-server-name", NAME]  # fmt: skip
        assert cli(argv) == 3
        err = capsys.readouterr().err
        lines = err.splitlines()
        assert lines[0].startswith("edgerv migrate: m: unsettled: "), err
        again = (
            f"edgerv migrate --from {edge} --to {cloud} --monitor m --timeout 0.4 --grace 0.25 "
            f"--ca-file '{ca}' --tls-server-name {NAME}"
        )
        assert lines[1] == (
            f"edgerv migrate: run `{again}` again once https://{edge} answer(s): it finishes "
            "the move or undoes it"
        )
        # no handshake with the edge ever finished: it took nothing; the cloud let go
        assert https.listed(0) == UNTOUCHED
        assert {k: https.listed(1)[k] for k in ("active", "handoff")} == {
            "active": False,
            "handoff": None,
        }
        gate.mode = "pass"
        words = shlex.split(lines[1].split("`")[1])
        assert words[:2] == ["edgerv", "migrate"]
        assert cli_main(words[1:]) == 0, capsys.readouterr().err
        assert https.listed(1)["active"] and not https.listed(0)["active"]
    finally:
        gate.close()


def test_the_command_to_run_again_is_the_one_given_quoted() -> None:
    """Each option given, at its value (a default given is the same command), each word
    quoted for a shell; the monitors once each, in order."""
    import argparse

    from edgerv.control import migrate_command as command

    parser = argparse.ArgumentParser()
    command.add_arguments(parser)
    args = parser.parse_args(
        ["--from", "http://edge:1", "--to", "cloud host:2", "--monitor", "b,a", "--monitor",
         "b", "--timeout", "2", "--grace", "0.125", "--ca-file", "my ca.crt",
         "--tls-server-name", "h.ns.svc"]
    )  # fmt: skip
    names = command.monitor_names(args.monitor)
    assert command.command_line(args, names) == (
        "edgerv migrate --from http://edge:1 --to 'cloud host:2' --monitor b,a --timeout 2 "
        "--grace 0.125 --ca-file 'my ca.crt' --tls-server-name h.ns.svc"
    )
    plain = parser.parse_args(["--from", "a:1", "--to", "b:2", "--monitor", "m"])
    assert command.command_line(plain, ["m"]) == "edgerv migrate --from a:1 --to b:2 --monitor m"


@pytest.mark.parametrize(
    ("argv", "said"),
    [
        (["--from", "a:x", "--to", "b:1", "--monitor", "m"],
         "argument --from: 'a:x': the port must be a number from 1 to 65535"),
        (["--from", "a:1", "--to", "ftp://b:1", "--monitor", "m"],
         "argument --to: 'ftp://b:1': the scheme must be http:// or https://, not ftp://"),
        (["--from", "a", "--to", "b:1", "--monitor", "m"],
         "argument --from: 'a' is not HOST:PORT: give the port, e.g. a:8470"),
        (["--from", "http://a:1/v1", "--to", "b:1", "--monitor", "m"],
         "argument --from: 'http://a:1/v1' is not HOST:PORT: a handler's address has no path"),
        (["--from", "a:1", "--to", "b:1", "--monitor", "m", "--timeout", "0"],
         "argument --timeout: '0' is not a number of seconds above 0"),
        (["--from", "a:1", "--to", "b:1", "--monitor", "m", "--timeout", "nan"],
         "argument --timeout: 'nan' is not a number of seconds above 0"),
        (["--from", "a:1", "--to", "b:1", "--monitor", "m", "--grace", "-1"],
         "argument --grace: '-1' is not a number of seconds from 0"),
        (["--from", "a:1", "--to", "b:1", "--monitor", " , "],
         "--monitor: error: names no monitor"),
        (["--from", "a:1", "--to", "https://a:1", "--monitor", "m"],
         "--to: error: https://a:1 is the handler of --from too"),
    ],
)  # fmt: skip
def test_bad_arguments_exit_2_at_their_flag(
    argv: list[str], said: str, capsys: pytest.CaptureFixture[str]
) -> None:
    try:
        code = cli(argv)
    except SystemExit as exited:  # argparse's own errors
        code = int(exited.code or 0)
    err = capsys.readouterr().err
    assert code == 2, err
    assert said in err and "Traceback" not in err and "internal error" not in err, err


def test_the_help_is_plain_text_with_the_defaults(capsys: pytest.CaptureFixture[str]) -> None:
    for command in ("migrate", "orchestrate"):
        with pytest.raises(SystemExit) as done:
            cli_main([command, "--help"])
        assert done.value.code == 0
        text = capsys.readouterr().out
        assert "``" not in text and ":func:" not in text and ":mod:" not in text, text
        assert "--timeout SECONDS" in text and "(default: 30.0)" in text, text
    assert "(default: 1.0)" in text and "(default: 0.95)" in text  # orchestrate's
    assert "(default: False)" not in text and "(default: None)" not in text
