"""A rotated token is followed without a restart: the handler's --token-file and the
operator's EDGERV_TOKEN_FILE are read again when the file changes, as the kubelet
updates a Secret mounted as a volume (a new directory, then a symbolic link swapped)."""

from __future__ import annotations

import logging
import os
from pathlib import Path

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient, Unauthorized
from edgerv.control.token import TokenFile
from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine
from edgerv_operator.config import ConfigError, OperatorConfig


def mounted(root: Path, token: str, version: int) -> Path:
    """Write ``token`` as the kubelet writes a Secret volume: into ``..v<version>/token``,
    then ``..data`` pointed at it, ``token`` a link through ``..data``."""
    data = root / f"..v{version}"
    data.mkdir()
    (data / "token").write_text(token + "\n")
    link = root / "..data_tmp"
    link.symlink_to(data.name)
    os.replace(link, root / "..data")  # atomic, as the kubelet does
    path = root / "token"
    if not path.is_symlink():
        path.symlink_to("..data/token")
    return path


def test_a_token_file_is_read_again_when_it_changes(
    tmp_path: Path, caplog: pytest.LogCaptureFixture
) -> None:
    path = mounted(tmp_path, "first", 1)
    token = TokenFile(path, check_every=0.0)
    assert token.value() == "first"
    mounted(tmp_path, "second", 2)
    assert token.value() == "second"
    (tmp_path / "..v2" / "token").write_text("  \n")  # emptied: the last token is kept
    with caplog.at_level(logging.WARNING, logger="edgerv.control.token"):
        assert token.value() == "second" and token.value() == "second"
    assert [r.getMessage() for r in caplog.records].count(
        f"{path}: cannot read the token (it is empty): keeping the last"
    ) == 1  # said once, not at every request
    (tmp_path / "..v2" / "token").write_text("third")
    assert token.value() == "third"


def test_a_token_file_is_looked_at_no_more_than_once_a_check_period(tmp_path: Path) -> None:
    path = mounted(tmp_path, "first", 1)
    token = TokenFile(path, check_every=3600.0)
    mounted(tmp_path, "second", 2)
    assert token.value() == "first"  # within the period: the value read


def test_an_unusable_token_file_is_refused_at_start(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError):
        TokenFile(tmp_path / "missing")
    (tmp_path / "empty").write_text("\n")
    with pytest.raises(ValueError, match="empty"):
        TokenFile(tmp_path / "empty")


def test_the_handler_and_its_client_follow_a_rotated_token(tmp_path: Path) -> None:
    """Both sides read the same kind of file: after a rotation the old token is refused
    (401: the client's Unauthorized) and the new one accepted, with no restart."""
    server_dir, client_dir = tmp_path / "server", tmp_path / "client"
    server_dir.mkdir()
    client_dir.mkdir()
    api = ControlApi(
        Engine("edge"),
        CollectorRegistry(),
        TokenFile(mounted(server_dir, "old", 1), check_every=0.0),
        on_change=lambda: None,
    )
    api.start("127.0.0.1", 0)
    try:
        client = HandlerClient(
            f"127.0.0.1:{api.port}", TokenFile(mounted(client_dir, "old", 1), check_every=0.0)
        )
        assert client.monitors() == []
        mounted(server_dir, "new", 2)  # the handler's node saw the new Secret first
        with pytest.raises(Unauthorized):
            client.monitors()
        mounted(client_dir, "new", 2)  # then the operator's
        assert client.monitors() == []
        assert HandlerClient(f"127.0.0.1:{api.port}", "new").monitors() == []
        with pytest.raises(Unauthorized):
            HandlerClient(f"127.0.0.1:{api.port}", "old").monitors()
    finally:
        api.stop()


def test_the_operator_reads_its_token_from_a_file_it_follows(tmp_path: Path) -> None:
    path = mounted(tmp_path, "from-the-secret", 1)
    env = {
        "EDGERV_NAMESPACE": "edgerv",
        "EDGERV_TOKEN_FILE": str(path),
        "EDGERV_TOKEN": "x",
        "EDGERV_PLAIN_HTTP": "true",
    }
    config = OperatorConfig.from_env(env)
    assert isinstance(config.token, TokenFile) and config.token.value() == "from-the-secret"
    for value, error in [
        (str(tmp_path / "missing"), "EDGERV_TOKEN_FILE: cannot read '.*missing'"),
        (str(tmp_path), "EDGERV_TOKEN_FILE: cannot read"),  # a directory
    ]:
        with pytest.raises(ConfigError, match=error):
            OperatorConfig.from_env({**env, "EDGERV_TOKEN_FILE": value})
    (tmp_path / "empty").write_text("")
    with pytest.raises(ConfigError, match=r"EDGERV_TOKEN_FILE: '.*empty' is empty or not text"):
        OperatorConfig.from_env({**env, "EDGERV_TOKEN_FILE": str(tmp_path / "empty")})
