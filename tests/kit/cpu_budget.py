"""A handler in a Docker container under a steady load, for the test of its CPU budget set
at run time (test_cpu_budget_docker.py): the container started by images/README.md's
``docker-setup`` and ``docker-run`` recipes, many monitors over one topic
(:func:`load_monitors`), a robot's publisher at a steady rate (:func:`load_publisher`),
and the handler's own status on ``/diagnostics`` as it publishes it (:class:`Diagnostics`).

The robot's processes discover the handler over ``SUBNET`` (images/README.md, "docker
run": a container has a /dev/shm of its own).
"""

from __future__ import annotations

import contextlib
import json
import os
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from kit import dockerimage, int32_publisher
from kit.pki import shared_pki
from kit.robotrun import https
from kit.ros import free_port, robot_env

LOAD_TOPIC = "/load"

LOAD_DOC = """apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: load-{i}}}
spec:
  assertion: "always (x >= 0)"
  signals:
    x: {{topic: /load, type: std_msgs/msg/Int32, field: data}}
"""


def load_monitors(n: int) -> str:
    """``n`` monitors of one Int32 topic that every message steps and none decides (the
    values published are all from 0): a load without verdicts to write."""
    return "---\n".join(LOAD_DOC.format(i=i) for i in range(n))


def load_publisher(domain: int, rate: float) -> subprocess.Popen[str]:
    """The robot's publisher on :data:`LOAD_TOPIC` at ``rate`` messages a second; its first
    line says "matched" once the handler subscribed (or "unmatched" after 60 s)."""
    return subprocess.Popen(
        int32_publisher.argv(LOAD_TOPIC, rate, name="load_publisher"),
        env=robot_env(domain, "SUBNET"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


# The handler's own status on /diagnostics, a JSON line each time it is published.
LISTEN = r"""
import json, sys, time, rclpy
from diagnostic_msgs.msg import DiagnosticArray
rclpy.init()
node = rclpy.create_node("diagnostics_listener")
def seen(msg):
    for s in msg.status:
        if s.name.startswith("edgerv handler: "):
            level = s.level[0] if isinstance(s.level, bytes) else s.level  # a byte field
            values = {kv.key: kv.value for kv in s.values}
            print(json.dumps({"at": time.monotonic(), "level": level, "message": s.message,
                              "values": values}), flush=True)
node.create_subscription(DiagnosticArray, "/diagnostics", seen, 10)
rclpy.spin(node)
"""


class Diagnostics:
    """The handler's statuses on /diagnostics, as a robot's tool (rqt_robot_monitor) sees
    them: ``statuses`` holds each as a dict (at: this machine's time.monotonic(), level,
    message, values), in the order published."""

    def __init__(self, domain: int) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, "-c", LISTEN],
            env=robot_env(domain, "SUBNET"),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        self.statuses: list[dict[str, Any]] = []
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.statuses.append(json.loads(line))

    def between(self, start: float, end: float) -> list[dict[str, Any]]:
        return [s for s in list(self.statuses) if start <= s["at"] <= end]

    def stop(self) -> None:
        self.proc.kill()
        self.proc.wait()


@dataclass(frozen=True)
class HandlerContainer:
    """The handler's container as images/README.md's recipe runs it; its API over TLS."""

    name: str
    port: int
    token: str
    ca: Path

    def get(self, path: str) -> Any:
        status, body = https(self.port, path, self.token, self.ca)
        assert status == 200, (path, status, body)
        return json.loads(body)

    def logs(self) -> str:
        done = dockerimage.docker("logs", self.name, check=False)
        return done.stdout + done.stderr

    def wait_ready(self, timeout: float = 90) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if " ready: " in self.logs():
                return
            time.sleep(0.2)
        raise AssertionError(f"the handler was not ready in {timeout:g} s:\n{self.logs()}")


@contextlib.contextmanager
def handler_container(
    tmp: Path, domain: int, image: str, monitors: str
) -> Iterator[HandlerContainer]:
    """The handler of ``image`` with ``monitors``, started by images/README.md's
    ``docker-setup`` and ``docker-run`` blocks (no CPU limit), ready; removed at the end."""
    _, etc, data = dockerimage.readme_setup(tmp, domain, monitors)
    port, name = free_port(), f"edgerv-budget-{os.getpid()}"
    run = dockerimage.readme_run(etc, data, image, name, f"0.0.0.0:{port}")
    container = HandlerContainer(name, port, (etc / "token").read_text().strip(), shared_pki().ca)
    try:
        done = subprocess.run(["bash", "-euc", run], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, done.stderr
        container.wait_ready()
        yield container
    finally:
        dockerimage.docker("rm", "--force", name, check=False)
