"""The handler's image under ``docker run``, as images/README.md's "docker run" section
says, on a robot without Kubernetes: the section's own two command blocks are run (only
their first lines' values changed: directories, the container's name, the port), against
a real rclpy publisher on the host; the verdicts in the log on the mounted volume equal
``edgerv check`` on the messages published.

The image is built from this working tree (kit/dockerimage.py: on the test cluster's
debootstrap base, docker's cache making a rebuild of unchanged sources quick). Skipped
only where Docker cannot run at all (no docker, no daemon and no root to start one).

ROS 2 discovery here is ``SUBNET`` (the recipe's, in a test domain of its own), not the
``LOCALHOST`` of the other integration tests: with ``LOCALHOST``, Fast DDS talks to the
machine's other processes through shared memory whatever its transports, which a
container with its own /dev/shm does not see (images/README.md says so).
"""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest

from kit import dockerimage
from kit.odom_run import MONITORS
from kit.pki import shared_pki
from kit.robotrun import https, log_verdicts, messages_taken, publish_run
from kit.ros import free_port, offline_verdicts, robot_env, wait_for

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def image() -> str:
    reason = dockerimage.why_no_docker()
    if reason is not None:
        pytest.skip(f"Docker cannot run here: {reason}")
    return dockerimage.handler_image()


class Container:
    """The container the recipe started, by name."""

    def __init__(self, name: str) -> None:
        self.name = name

    def inspect(self) -> dict[str, Any]:
        out = dockerimage.docker("inspect", self.name).stdout
        return json.loads(out)[0]  # type: ignore[no-any-return]

    def logs(self) -> str:
        done = dockerimage.docker("logs", self.name, check=False)
        return done.stdout + done.stderr

    def wait_ready(self, times: int = 1, timeout: float = 60) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.logs().count(" ready: ") >= times:
                return
            state = self.inspect()["State"]
            if not state["Running"] and not state["Restarting"] and state["ExitCode"] != 0:
                raise AssertionError(f"the handler exited {state['ExitCode']}:\n{self.logs()}")
            time.sleep(0.2)
        raise AssertionError(f"the handler was not ready {times} time(s):\n{self.logs()}")

    def handler_pid(self) -> int:
        """The handler's process on the host: the only child of the container's init."""
        init = self.inspect()["State"]["Pid"]
        children = Path(f"/proc/{init}/task/{init}/children").read_text().split()
        assert len(children) == 1, children
        return int(children[0])


def test_the_documented_docker_run_gives_the_verdicts_of_edgerv_check(
    image: str, tmp_path: Path, domain: int
) -> None:
    certs = shared_pki()
    env_file = (ROOT / "packaging" / "handler.env").read_text()
    assert re.search(r"^ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET$", env_file, re.M)
    assert re.search(r"^FASTDDS_BUILTIN_TRANSPORTS=UDPv4$", env_file, re.M)
    work, etc, data = dockerimage.readme_setup(tmp_path, domain, MONITORS)
    assert oct(os.stat(etc / "tls.key").st_mode & 0o777) == "0o640"

    port, name = free_port(), f"edgerv-test-{os.getpid()}"
    run = dockerimage.readme_run(etc, data, image, name, f"0.0.0.0:{port}")
    container = Container(name)
    started = time.monotonic()
    try:
        done = subprocess.run(["bash", "-euc", run], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        container.wait_ready()
        print(f"\ncontainer ready {time.monotonic() - started:.1f} s after docker run")
        config = container.inspect()
        assert config["HostConfig"]["NetworkMode"] == "host"
        assert config["HostConfig"]["RestartPolicy"]["Name"] == "unless-stopped"
        assert config["HostConfig"]["ReadonlyRootfs"] is True
        assert config["Config"]["User"] == "10001:10001"
        token = (etc / "token").read_text().strip()
        assert token not in json.dumps(config)  # a file, not an argument or a variable

        # a crash: Docker starts the handler again
        os.kill(container.handler_pid(), 9)
        wait_for(lambda: container.inspect()["RestartCount"] == 1, timeout=30)
        container.wait_ready(times=2)

        # the robot's run
        trace = tmp_path / "run.jsonl"
        published = publish_run(trace, robot_env(domain, "SUBNET"))
        taken = wait_for(
            lambda: (t := messages_taken(port, certs.ca)) == published and t, timeout=30
        )
        assert taken == published, (taken, published, container.logs())

        # the API: the token over verified TLS, nothing without it
        status, body = https(port, "/v1/monitors", token, certs.ca)
        assert status == 200, body
        monitors = {m["name"]: m for m in json.loads(body)["monitors"]}
        assert set(monitors) == {"speed-limit", "no-stop-while-fast"}
        assert all(m["active"] and m["handler"] == socket.gethostname() for m in monitors.values())
        assert https(port, "/v1/monitors", None, certs.ca)[0] == 401
        assert https(port, "/v1/monitors", "not-the-token", certs.ca)[0] == 401

        # docker stop: SIGTERM; the handler flushes and exits 0 within the stop timeout
        stop_timeout = config["Config"]["StopTimeout"]
        began = time.monotonic()
        dockerimage.docker("stop", name, timeout=stop_timeout + 30)
        took = time.monotonic() - began
        state = container.inspect()["State"]
        print(f"docker stop took {took:.1f} s (stop timeout {stop_timeout} s)")
        assert state["ExitCode"] == 0, container.logs()
        assert not state["OOMKilled"]
        assert took < stop_timeout, took
        assert "SIGTERM: stopping" in container.logs()
    finally:
        logs = container.logs()
        dockerimage.docker("rm", "--force", name, check=False)

    log = (data / "verdicts.jsonl").read_text()
    offline = offline_verdicts(work / "monitors" / "robot.yaml", trace)
    assert len(offline) > 20
    assert log_verdicts(log) == offline, logs
    assert {json.loads(line)["handler"] for line in log.splitlines()} == {socket.gethostname()}
