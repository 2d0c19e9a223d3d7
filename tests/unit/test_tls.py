"""The control API over TLS (docs/handler.md, "TLS"): real HTTPS between in-process
handlers (engines fed directly, no ROS) and their callers, with certificates made by
``openssl`` (an independent issuer, as a user's or cert-manager's would be).

What is checked: a caller that trusts the handler's CA reaches it by its address and by
the name its certificate carries; a caller that does not (another CA, another name) is
refused before anything is sent and told so; a plain-HTTP caller gets nothing, and
failed handshakes never use up the handler's connections; a whole migration runs over
HTTPS; the handler refuses to serve plain HTTP off loopback unless asked by name.
"""

from __future__ import annotations

import argparse
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.cli import main as cli_main
from edgerv.control.client import (
    HandlerClient,
    ServerError,
    Unauthorized,
    Untrusted,
    WrongScheme,
)
from edgerv.control.migrate import migrate
from edgerv.control.tls import ClientTls, server_context
from edgerv.core.diagnostics import InputError
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv.handler.limits import Limits
from edgerv.handler.main import add_arguments, serving_tls
from kit.documents import compiled
from kit.engines import Feed, robot_feed
from kit.pki import NAME, Pki, make_pki

TOKEN = "test-token"


@pytest.fixture(scope="module")
def pki(tmp_path_factory: pytest.TempPathFactory) -> Pki:
    return make_pki(tmp_path_factory.mktemp("pki"))


def serve(engine: Engine, pki: Pki, connections: int = 64) -> ControlApi:
    api = ControlApi(
        engine, CollectorRegistry(), TOKEN, on_change=lambda: None,
        limits=Limits(connections=connections, read_seconds=2.0),
    )  # fmt: skip
    api.start("127.0.0.1", 0, tls=server_context(str(pki.crt), str(pki.key)))
    return api


@pytest.fixture
def handler(pki: Pki) -> Iterator[ControlApi]:
    engine = Engine("edge", flush_after=1e9)
    engine.put(compiled("always (a -> x < 5)", {"a": "bool", "x": "float"}), active=True)
    api = serve(engine, pki)
    yield api
    api.stop()


def test_a_caller_that_trusts_the_ca_reaches_the_handler_by_address_or_by_name(
    handler: ControlApi, pki: Pki
) -> None:
    by_address = HandlerClient(f"127.0.0.1:{handler.port}", TOKEN, ClientTls(str(pki.ca)))
    assert by_address.base.startswith("https://")
    assert [m["name"] for m in by_address.monitors()] == ["m"]
    by_name = HandlerClient(f"127.0.0.1:{handler.port}", TOKEN, ClientTls(str(pki.ca), NAME))
    assert [m["name"] for m in by_name.monitors()] == ["m"]
    wrong_token = HandlerClient(f"127.0.0.1:{handler.port}", "nope", ClientTls(str(pki.ca)))
    with pytest.raises(Unauthorized):
        wrong_token.monitors()


@pytest.mark.parametrize(
    "ca, name, why",
    [
        ("stranger", None, "unable to get local issuer"),
        (None, None, "unable to get local issuer|self.signed"),  # the system's CAs
        ("ca", "edgerv-handler.other.svc", "Hostname mismatch|doesn't match"),
    ],
)
def test_a_caller_that_does_not_trust_the_certificate_sends_nothing_and_is_told_why(
    handler: ControlApi, pki: Pki, ca: str | None, name: str | None, why: str
) -> None:
    tls = ClientTls(None if ca is None else str(getattr(pki, ca)), name)
    client = HandlerClient(f"https://127.0.0.1:{handler.port}", TOKEN, tls)
    with pytest.raises(Untrusted, match=f"its certificate is not trusted \\(({why})"):
        client.monitors()
    assert handler.engine.slots["m"].active  # nothing reached it


def test_an_impostor_with_another_cas_certificate_is_not_trusted(pki: Pki) -> None:
    """A handler whose certificate carries the right name and address but was signed by
    another CA (an impostor on the link): the caller refuses it."""
    engine = Engine("impostor", flush_after=1e9)
    api = ControlApi(engine, CollectorRegistry(), TOKEN, on_change=lambda: None)
    api.start("127.0.0.1", 0, tls=server_context(str(pki.other_crt), str(pki.other_key)))
    try:
        client = HandlerClient(f"127.0.0.1:{api.port}", TOKEN, ClientTls(str(pki.ca), NAME))
        with pytest.raises(Untrusted, match="not trusted \\(unable to get local issuer"):
            client.monitors()
    finally:
        api.stop()


def test_failed_handshakes_never_use_up_the_handlers_connections(
    pki: Pki,
) -> None:
    """Plain-HTTP callers and callers that refuse the certificate fail their handshake;
    each gives back its place under the connection cap at once (asyncio never tells the
    protocol of a handshake that failed): three times the cap of them, then a good caller
    is served."""
    engine = Engine("edge", flush_after=1e9)
    api = serve(engine, pki, connections=4)
    try:
        for i in range(12):
            if i % 2:
                plain = HandlerClient(f"http://127.0.0.1:{api.port}", TOKEN)
                with pytest.raises(WrongScheme, match="speaks HTTPS"):
                    plain.call("/v1/monitors", method="GET", timeout=2.0)
            else:
                stranger = ClientTls(str(pki.stranger))
                with pytest.raises(Untrusted):
                    HandlerClient(f"127.0.0.1:{api.port}", TOKEN, stranger).monitors()
        deadline = time.monotonic() + 2.0
        while api_open(api) and time.monotonic() < deadline:  # the server's side closes
            time.sleep(0.01)
        assert api_open(api) == 0
        good = HandlerClient(f"127.0.0.1:{api.port}", TOKEN, ClientTls(str(pki.ca)))
        assert good.monitors() == []
    finally:
        api.stop()


def api_open(api: ControlApi) -> int:
    """The connections the API counts toward its cap now (read on its loop's thread)."""
    loop = api._loop
    assert loop is not None
    got: list[int] = []
    done = threading.Event()

    def read() -> None:
        assert api.connections is not None
        got.append(api.connections.open)
        done.set()

    loop.call_soon_threadsafe(read)
    done.wait(2.0)
    return got[0]


class HeldFirst(HandlerClient):
    """A handler of a move whose receiver subscribes only once the sender holds and the
    robot has published one more pair, however busy the machine: the events between
    are the sender's alone, and cross as the snapshot's letters (migrate sends the two
    steps at once; the receiver first, it hears all the sender holds, none are letters)."""

    def __init__(self, held: threading.Event, feed: Feed, *args: Any) -> None:
        super().__init__(*args)
        self.held, self.feed = held, feed

    def handoff(self, step: str, *args: Any, **kwargs: Any) -> tuple[int, bytes]:
        if step == "receive" and not self.held.wait(30.0):
            raise TimeoutError("the sender did not hold in 30 s")
        answer = super().handoff(step, *args, **kwargs)
        if step == "hold":
            self.feed.wait_round()
            self.held.set()
        return answer


def test_a_migration_runs_over_https(pki: Pki) -> None:
    edge, cloud = Engine("edge", flush_after=1e9), Engine("cloud", flush_after=1e9)
    monitor = compiled("always (a -> x < 5)", {"a": "bool", "x": "float"})
    edge.put(monitor, active=True)
    cloud.put(monitor, active=False)
    apis = [serve(e, pki) for e in (edge, cloud)]
    try:
        with robot_feed([edge, cloud]) as feed:
            tls = ClientTls(str(pki.ca), NAME)
            held = threading.Event()
            source, destination = (
                HeldFirst(held, feed, f"127.0.0.1:{a.port}", TOKEN, tls) for a in apis
            )
            moved = migrate(source, destination, ["m"], 5.0, 0.5)
        assert moved.letters > 0
        assert not edge.slots["m"].active and cloud.slots["m"].active
    finally:
        for api in apis:
            api.stop()


def handler_args(*argv: str) -> argparse.Namespace:
    p = argparse.ArgumentParser()
    add_arguments(p)
    return p.parse_args(["--name", "h", *argv])


def test_the_handler_serves_plain_http_only_on_loopback_or_when_asked_by_name(
    pki: Pki,
) -> None:
    assert serving_tls(handler_args("--listen", "127.0.0.1:0")) is None
    assert serving_tls(handler_args("--listen", "10.1.2.3:0", "--plain-http")) is None
    with pytest.raises(InputError, match=r"--listen: error: 10\.1\.2\.3 is not a loopback address"):
        serving_tls(handler_args("--listen", "10.1.2.3:0"))
    with pytest.raises(InputError, match="--tls-key: error: given without --tls-cert"):
        serving_tls(handler_args("--listen", "10.1.2.3:0", "--tls-key", str(pki.key)))
    tls = serving_tls(
        handler_args("--listen", "0.0.0.0:0", "--tls-cert", str(pki.crt), "--tls-key",
                     str(pki.key)),
    )  # fmt: skip
    assert tls is not None


def test_bad_certificate_files_are_named_and_the_handler_exits_2(
    pki: Pki, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    missing = tmp_path / "missing.crt"
    code = cli_main(
        ["handler", "--name", "h", "--listen", "10.1.2.3:0", "--insecure",
         "--tls-cert", str(missing), "--tls-key", str(pki.key)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and f"{missing}: error: cannot use the certificate" in err, err
    assert "Traceback" not in err
    code = cli_main(
        ["handler", "--name", "h", "--listen", "10.1.2.3:0", "--insecure",
         "--tls-cert", str(pki.other_crt), "--tls-key", str(pki.key)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and "cannot use the certificate with the key" in err, err
    code = cli_main(
        ["migrate", "--from", "a:1", "--to", "b:2", "--monitor", "m",
         "--ca-file", str(missing)]
    )  # fmt: skip
    err = capsys.readouterr().err
    assert code == 2 and f"{missing}: error: cannot use the CA certificate" in err, err


def test_the_connection_cap_holds_over_tls(pki: Pki) -> None:
    """Over TLS a place is taken by a request with the token, as over plain HTTP: two
    idle callers hold none; two with a request under way (a body on its way) hold a cap
    of two, and a third request with the token gets the 503 that says so, over TLS."""
    engine = Engine("edge", flush_after=1e9)
    api = serve(engine, pki, connections=2)
    tls = ClientTls(str(pki.ca))
    idle = [tls.connection("127.0.0.1", api.port, 5.0) for _ in range(2)]
    held = [tls.connection("127.0.0.1", api.port, 5.0) for _ in range(2)]
    try:
        for conn in idle:
            conn.connect()
        third = HandlerClient(f"127.0.0.1:{api.port}", TOKEN, tls)
        assert third.monitors() == []
        third.close()
        for conn in held:
            conn.putrequest("PUT", "/v1/monitors/m")
            conn.putheader("Authorization", f"Bearer {TOKEN}")
            conn.putheader("Content-Length", "100")
            conn.endheaders()  # the body never comes
        deadline = time.monotonic() + 2.0
        while api_open(api) < 2 and time.monotonic() < deadline:
            time.sleep(0.01)
        with pytest.raises(ServerError, match="at most 2 clients' connections at once"):
            third.monitors()
        for conn in held:
            conn.close()
        deadline = time.monotonic() + 2.0
        while api_open(api) and time.monotonic() < deadline:
            time.sleep(0.01)
        assert third.monitors() == []
    finally:
        for conn in [*idle, *held]:
            conn.close()
        api.stop()


def test_the_operator_calls_the_handlers_over_https_with_the_charts_ca(pki: Pki) -> None:
    from edgerv_operator.config import OperatorConfig

    env = {
        "EDGERV_TOKEN": TOKEN,
        "EDGERV_NAMESPACE": "test",
        "EDGERV_TLS_CA_FILE": str(pki.ca),
        "EDGERV_TLS_SERVER_NAME": NAME,
    }
    config = OperatorConfig.from_env(env)
    assert config.tls is not None and config.url("10.0.0.2:8470") == "https://10.0.0.2:8470"
    engine = Engine("edge", flush_after=1e9)
    api = serve(engine, pki)
    try:
        client = HandlerClient(config.url(f"127.0.0.1:{api.port}"), config.token, config.tls)
        assert client.monitors() == []
    finally:
        api.stop()
