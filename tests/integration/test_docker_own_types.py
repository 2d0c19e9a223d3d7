"""A robot's own message types in the handler's image (issue #39), as images/README.md's
"Your own message types in the handler's image" says: the packages of kit.own_types
(nested types, arrays, a type of another custom package) built as wheels by ``edgerv
types build SRC --wheel-dir types``, installed into an image of the reader's own by the
section's Dockerfile (``FROM edgerv/handler:dev``: no rebuild of the handler's image),
that image run by the "docker run" section's own command blocks (only their first lines'
values changed) with monitors on those types; a real rclpy node on the host, built from
the same packages, publishes; a recorder node next to it records an MCAP bag; the
verdicts in the log on the mounted volume equal ``edgerv check`` on the bag, stamps
included.

The handler's image comes from kit.dockerimage (built once, reused when nothing
changed); the types' build is kept in the tests' cache (``$EDGERV_CACHE``, else
~/.cache/edgerv: ``test-types``), so only a first run builds them (about 20 s a package
on 2 cores). Skipped only where Docker cannot run at all. ROS 2 discovery is ``SUBNET``,
as test_docker_run.py's (the reasons are there).
"""

from __future__ import annotations

import base64
import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("rclpy")

from edgerv.handler.ros import types as ros_types
from kit import dockerimage
from kit.own_types import (
    MONITOR_NAMES,
    MONITORS,
    PUBLISHER,
    N,
    write_bag,
    write_packages,
)
from kit.pki import shared_pki
from kit.robotrun import messages_taken
from kit.ros import check_verdicts, free_port, robot_env, wait_for

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
IMAGE = "edgerv-test/handler-own-types:dev"  # the reader's own image (the README's my-robot/...)

# A recorder next to the handler, as `ros2 bag record` would be: a real rclpy node of the
# robot's machine subscribed to /state (the class from the same cached build as the
# publisher's), writing each message's CDR bytes as received and its arrival, once it has
# N (or after 120 s) and 3 s more; it says "recording" once its subscription exists.
RECORDER = r"""
import base64, json, sys, time
import rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from edgerv.handler.ros.types import load_package
load_package("my_robot_msgs")
from my_robot_msgs.msg import State
out, n = sys.argv[1], int(sys.argv[2])
rclpy.init()
node = rclpy.create_node("recorder")
got = []
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
node.create_subscription(State, "/state", lambda raw: got.append((raw, time.time_ns())), qos,
                         raw=True)
print("recording", flush=True)
deadline = time.monotonic() + 120
while len(got) < n and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.1)
linger = time.monotonic() + 3  # matched still when the publisher counts its subscribers
while time.monotonic() < linger:
    rclpy.spin_once(node, timeout_sec=0.1)
with open(out, "w") as f:
    for raw, at in got:
        f.write(json.dumps({"at": at, "cdr": base64.b64encode(raw).decode()}) + "\n")
print(len(got), flush=True)
"""


@pytest.fixture(scope="module")
def base_image() -> str:
    reason = dockerimage.why_no_docker()
    if reason is not None:
        pytest.skip(f"Docker cannot run here: {reason}")
    return dockerimage.handler_image()


def logs(name: str) -> str:
    done = dockerimage.docker("logs", name, check=False)
    return done.stdout + done.stderr


def wait_ready(name: str, timeout: float = 60) -> None:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if " ready: " in logs(name):
            return
        state: dict[str, Any] = json.loads(dockerimage.docker("inspect", name).stdout)[0]["State"]
        if not state["Running"] and not state["Restarting"] and state["ExitCode"] != 0:
            raise AssertionError(f"the handler exited {state['ExitCode']}:\n{logs(name)}")
        time.sleep(0.2)
    raise AssertionError(f"the handler was not ready:\n{logs(name)}")


def test_the_documented_image_of_ones_own_types_gives_the_verdicts_of_edgerv_check(
    base_image: str, tmp_path: Path, domain: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    assert base_image == "edgerv/handler:dev"  # what the README's Dockerfile is FROM
    src = write_packages(tmp_path / "robot_ws" / "src")
    # the types' build, kept between runs; the host's nodes load the same build from it
    monkeypatch.setenv(ros_types.CACHE_ENV, str(dockerimage.cluster.CACHE / "test-types"))
    monkeypatch.setenv("EDGERV_MSG_PATH", str(src))  # the host's nodes and edgerv check

    # the reader's image: the README's Dockerfile and commands, in a directory of its own
    context = tmp_path / "my-image"
    context.mkdir()
    (context / "Dockerfile").write_text(dockerimage.readme_recipe("types-dockerfile", "dockerfile"))
    build = dockerimage.with_values(
        dockerimage.readme_recipe("types-image"), {"SRC": str(src), "IMAGE": IMAGE}
    )
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    started = time.monotonic()
    done = subprocess.run(
        ["bash", "-euc", build], cwd=context, env=env, capture_output=True, text=True, timeout=900
    )
    assert done.returncode == 0, done.stdout[-4000:] + done.stderr[-4000:]
    wheels = sorted(p.name.split("-")[0] for p in (context / "types").glob("*.whl"))
    assert wheels == ["common_msgs", "my_robot_msgs"], done.stdout
    print(f"\ntypes built and image {IMAGE} made in {time.monotonic() - started:.1f} s")

    # in the image: the types import from the wheels, the .msg files are in share/
    probe = dockerimage.docker(
        "run", "--rm", "--network", "none", "--entrypoint", "/opt/edgerv/bin/python", IMAGE,
        "-c", "import sys, my_robot_msgs.msg as m, common_msgs.msg as c; "
        "m.State.__class__.__import_type_support__(); print(m.__file__); "
        "print(open(sys.prefix + '/share/my_robot_msgs/msg/State.msg').read())",
    )  # fmt: skip
    assert probe.stdout.startswith("/opt/edgerv/lib/python3"), probe.stdout
    assert "common_msgs/Vec2[2] corners" in probe.stdout, probe.stdout

    # what a reader has at hand: handler.env (the domain set), the certificate, the monitors
    certs = shared_pki()
    work, etc, data = dockerimage.readme_setup(tmp_path, domain, MONITORS)

    port, name = free_port(), f"edgerv-test-types-{os.getpid()}"
    run = dockerimage.readme_run(etc, data, IMAGE, name, f"127.0.0.1:{port}")
    recorded_at = tmp_path / "recorded.jsonl"
    try:
        done = subprocess.run(["bash", "-euc", run], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        wait_ready(name)
        console = logs(name)
        assert "ready: 4 of 4 monitors active" in console, console
        assert "building the message types" not in console, console  # installed, not built

        # the robot: a recorder, then the publisher (it waits for the handler and the recorder)
        robot = robot_env(domain, "SUBNET")
        recorder = subprocess.Popen(
            [sys.executable, "-c", RECORDER, str(recorded_at), str(N)],
            env=robot, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )  # fmt: skip
        try:
            assert recorder.stdout is not None
            assert recorder.stdout.readline().strip() == "recording", recorder.stderr
            pub = subprocess.run(
                [sys.executable, "-c", PUBLISHER, str(N), "2"],
                env=robot, capture_output=True, text=True, timeout=180,
            )  # fmt: skip
            assert pub.returncode == 0, pub.stderr
            report: dict[str, Any] = json.loads(pub.stdout.strip().splitlines()[-1])
            assert report["matched"] == 2, report  # the handler in its container, the recorder
            out, err = recorder.communicate(timeout=150)
        finally:
            if recorder.poll() is None:
                recorder.kill()
                recorder.wait()
        assert recorder.returncode == 0, err
        assert int(out.strip().splitlines()[-1]) == N, (out, err)
        taken = wait_for(
            lambda: messages_taken(port, certs.ca).get("/state") == N, timeout=30
        )  # fmt: skip
        assert taken, (messages_taken(port, certs.ca), logs(name))

        dockerimage.docker("stop", name, timeout=60)
        state = json.loads(dockerimage.docker("inspect", name).stdout)[0]["State"]
        assert state["ExitCode"] == 0, logs(name)
    finally:
        console = logs(name)
        dockerimage.docker("rm", "--force", name, check=False)

    recorded = [
        (base64.b64decode(r["cdr"]), r["at"])
        for r in map(json.loads, recorded_at.read_text().splitlines())
    ]
    bag = tmp_path / "recorded.mcap"
    write_bag(bag, recorded)
    offline = check_verdicts(work / "monitors" / "robot.yaml", bag)
    live = sorted(
        (v["monitor"], v["verdict"], v["step"], v["stamp"])
        for v in map(json.loads, (data / "verdicts.jsonl").read_text().splitlines())
    )
    assert {m for m, *_ in offline} == MONITOR_NAMES
    assert len(offline) > 40
    assert live == offline, console
