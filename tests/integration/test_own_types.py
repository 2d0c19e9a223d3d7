"""A robot's own message types, live (issue #39): a custom interface package written here
(nested types, arrays, a type of another custom package, standard ones), found by the
handler under $EDGERV_MSG_PATH as ``edgerv check`` finds it, built with rosidl at its first
use into a types cache (edgerv.handler.ros.types: a real ament/rosidl build from PyPI's
ros-jazzy-* wheels, no ROS installation); a real rclpy publisher node imports the
generated classes and publishes; a recorder node next to the handler records the same
messages as an MCAP bag; the handler's verdicts equal ``edgerv check`` on the bag. Then
``edgerv types build --wheel-dir`` packs the packages as wheels that pip installs, and
the types import from there with no cache and no .msg files.

The first build takes about 20 s a package on 2 cores (two packages here).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import pytest

rclpy = pytest.importorskip("rclpy")

from rclpy.qos import QoSProfile, ReliabilityPolicy  # noqa: E402

from edgerv.handler.ros import types as ros_types  # noqa: E402
from kit.own_types import MONITORS, PUBLISHER, N, write_bag, write_packages  # noqa: E402
from kit.ros import HandlerProcess, check_verdicts, own_node, ros_env, wait_for  # noqa: E402

pytestmark = pytest.mark.integration


class FirstUse(HandlerProcess):
    """A handler that builds its monitors' types before it is ready: it may take minutes."""

    def wait_ready(self, timeout: float = 600) -> None:
        super().wait_ready(timeout)


@pytest.fixture(scope="module")
def place(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The definitions (common_msgs, my_robot_msgs) and a types cache, empty at first,
    shared by the tests here (the second finds the first's build)."""
    top = tmp_path_factory.mktemp("own-types")
    defs = write_packages(top / "defs")
    return {"defs": defs, "cache": top / "cache", "top": top}


@pytest.fixture
def own_env(place: dict[str, Path], monkeypatch: pytest.MonkeyPatch) -> dict[str, Path]:
    """$EDGERV_MSG_PATH and the types cache, for this process and the processes it starts."""
    monkeypatch.setenv("EDGERV_MSG_PATH", str(place["defs"]))
    monkeypatch.setenv(ros_types.CACHE_ENV, str(place["cache"]))
    return place


def test_live_verdicts_on_a_custom_package_built_at_first_use_equal_edgerv_check(
    own_env: dict[str, Path], tmp_path: Path, domain: int
) -> None:
    monitors = tmp_path / "monitors.yaml"
    monitors.write_text(MONITORS)
    cache = own_env["cache"]
    started = time.monotonic()
    # --types-cache: the flag (the publisher and this process take the same cache from
    # $EDGERV_TYPES_CACHE)
    handler = FirstUse(tmp_path, monitors, domain, "--types-cache", str(cache))
    first_use = time.monotonic() - started
    try:
        stderr = handler.stderr
        assert "building the message types of common_msgs" in stderr, stderr
        assert "building the message types of my_robot_msgs" in stderr, stderr
        assert "ready: 4 of 4 monitors active" in stderr, stderr
        assert sorted(p.name.split("-")[0] for p in cache.iterdir() if p.is_dir()) == [
            "common_msgs",
            "my_robot_msgs",
        ]
        print(f"handler ready after building the types: {first_use:.1f} s")

        # this process's recorder needs the class too (the cached build, loaded here)
        ros_types.load_package("my_robot_msgs")
        from my_robot_msgs.msg import State

        recorded: list[tuple[bytes, int]] = []
        qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        with own_node(domain, "recorder") as node:
            node.create_subscription(
                State, "/state", lambda raw: recorded.append((raw, time.time_ns())), qos, raw=True
            )
            env = ros_env(domain)
            pub = subprocess.run(
                [sys.executable, "-c", PUBLISHER, str(N), "2"],
                env=env,
                capture_output=True,
                text=True,
                timeout=180,
            )
            assert pub.returncode == 0, pub.stderr
            report: dict[str, Any] = json.loads(pub.stdout.strip().splitlines()[-1])
            assert report["matched"] == 2, report  # the handler and the recorder
            assert Path(report["from"]).is_relative_to(cache)  # the generated code, cached
            assert wait_for(lambda: len(recorded) == N, timeout=20), len(recorded)
        assert wait_for(
            lambda: handler.metric("edgerv_messages_total", topic="/state") == N, timeout=20
        ), handler.metric("edgerv_messages_total", topic="/state")
    finally:
        assert handler.stop() == 0, handler.stderr
    bag = tmp_path / "recorded.mcap"
    write_bag(bag, recorded)
    offline = check_verdicts(monitors, bag)
    live = sorted((v["monitor"], v["verdict"], v["step"], v["stamp"]) for v in handler.verdicts())
    assert {m for m, *_ in offline} == {"battery", "no-slip-under-load", "corner-inside",
                                        "target-near"}  # fmt: skip
    assert len(offline) > 40
    assert live == offline


def test_a_second_handler_finds_the_types_built(
    own_env: dict[str, Path], tmp_path: Path, domain: int
) -> None:
    """The cache holds the build: another handler is ready at once, nothing is built."""
    monitors = tmp_path / "monitors.yaml"
    monitors.write_text(MONITORS)
    subprocess.run(  # (built here if this test runs alone)
        [sys.executable, "-m", "edgerv", "types", "build", str(own_env["defs"])],
        check=True,
        capture_output=True,
        timeout=600,
    )
    started = time.monotonic()
    handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        assert time.monotonic() - started < 25
        assert "building the message types" not in handler.stderr
        assert "ready: 4 of 4 monitors active" in handler.stderr
    finally:
        assert handler.stop() == 0, handler.stderr


def test_edgerv_types_build_packs_wheels_that_pip_installs_and_that_import_alone(
    own_env: dict[str, Path], tmp_path: Path
) -> None:
    wheels, prefix = tmp_path / "wheels", tmp_path / "installed"
    built = subprocess.run(
        [sys.executable, "-m", "edgerv", "types", "build", str(own_env["defs"]),
         "--wheel-dir", str(wheels)],
        capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert built.returncode == 0, built.stderr
    names = sorted(p.name.split("-")[0] for p in wheels.glob("*.whl"))
    assert names == ["common_msgs", "my_robot_msgs"], built.stdout
    assert "pip install --no-deps" in built.stderr
    # installed as pip installs into a venv (here a prefix of its own: the shared venv stays)
    subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--prefix",
         str(prefix), *map(str, sorted(wheels.glob("*.whl")))],
        check=True, timeout=300,
    )  # fmt: skip
    py = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    env = dict(os.environ)
    env.pop("EDGERV_MSG_PATH")
    env.update(
        {
            ros_types.CACHE_ENV: "none",  # nothing may be built: it must import as installed
            "PYTHONPATH": str(prefix / "lib" / py / "site-packages"),
            # (what a venv's lib/ is to its wheels: ros_wheels_bootstrapper's, set already)
            "LD_LIBRARY_PATH": os.pathsep.join([str(prefix / "lib"), env["LD_LIBRARY_PATH"]]),
            "AMENT_PREFIX_PATH": str(prefix),  # edgerv check's .msg files: <prefix>/share
        }
    )
    probe = r"""
import sys
from rclpy.serialization import deserialize_message, serialize_message
from edgerv.core.msgtypes import field_kind
from edgerv.handler.ros.messages import message_class
State, Vec2 = message_class("my_robot_msgs/msg/State"), message_class("common_msgs/msg/Vec2")
msg = State(mode="AUTO", corners=[Vec2(x=1.0), Vec2(y=2.0)], codes=[3])
assert deserialize_message(serialize_message(msg), State) == msg
assert field_kind("my_robot_msgs/msg/State", "wheels[0].force.x") == "float"
print(sys.modules[State.__module__].__file__)
"""
    done = subprocess.run(
        [sys.executable, "-c", probe], env=env, capture_output=True, text=True, timeout=60
    )
    assert done.returncode == 0, done.stderr
    assert Path(done.stdout.strip()).is_relative_to(prefix)
