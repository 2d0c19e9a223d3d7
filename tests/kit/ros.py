"""The ROS process harness of the integration tests (and the benches): an ``edgerv
handler`` process, small ROS 2 publishers, ``edgerv replay`` and ``edgerv migrate`` as
processes, a node of the test's own, and :func:`ros_env`, the one environment builder of
every ROS 2 process they start.

Every process gets a ROS domain of its test's own and discovery limited to
localhost, so tests neither see each other nor send anything off this machine.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from kit.pki import NAME, shared_pki

TOKEN = "integration-secret"


@contextlib.contextmanager
def own_node(domain: int, name: str) -> Iterator[Any]:
    """An rclpy node of the test process in ``domain`` (a context of its own, discovery on
    localhost as the processes here), spun by an executor thread until the block ends."""
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    context = rclpy.context.Context()
    rclpy.init(context=context, domain_id=domain)
    node = rclpy.create_node(name, context=context)
    executor = SingleThreadedExecutor(context=context)
    executor.add_node(node)
    spinner = threading.Thread(target=executor.spin, daemon=True)
    spinner.start()
    try:
        yield node
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=context)
        spinner.join(timeout=5)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def ros_env(domain: int | str, discovery: str = "LOCALHOST", **extra: str) -> dict[str, str]:
    """The environment of a ROS 2 process: this one's, in the ROS domain ``domain``, with
    discovery over ``discovery`` (LOCALHOST: nothing leaves this machine), unbuffered
    output, and ``extra`` on top (EDGERV_TOKEN=..., say)."""
    return {
        **os.environ,
        "ROS_DOMAIN_ID": str(domain),
        "ROS_AUTOMATIC_DISCOVERY_RANGE": discovery,
        "PYTHONUNBUFFERED": "1",
        **extra,
    }


def robot_env(domain: int, discovery: str) -> dict[str, str]:
    """The environment of a robot's own process (not the tests' harness): :func:`ros_env`
    with Fast DDS's default transports (the robot's own, whatever this machine's are)."""
    env = ros_env(domain, discovery)
    env.pop("FASTDDS_BUILTIN_TRANSPORTS", None)
    return env


REQUEST = r"""
import ssl, sys, http.client
method, host, port, path, body, token, ca, name = sys.argv[1:9]
headers = {"Content-Type": "application/yaml"}
if token:
    headers["Authorization"] = "Bearer " + token
context = ssl.create_default_context(cafile=ca)
conn = http.client.HTTPSConnection(host, int(port), timeout=30, context=context)
conn.connect = lambda: setattr(conn, "sock", context.wrap_socket(
    __import__("socket").create_connection((host, int(port)), 30), server_hostname=name))
conn.request(method, path, body=body.encode() or None, headers=headers)
resp = conn.getresponse()
sys.stdout.write(str(resp.status) + "\n" + resp.read().decode())
"""


class HandlerProcess:
    """An ``edgerv handler`` process with its API on a free loopback port.

    With ``lab`` (a :class:`netlab.Lab`), it runs on the lab's host ``name``
    (``edge`` or ``cloud``) and serves HTTPS on that host's address, with a certificate
    for :data:`pki.NAME` (:func:`pki.shared_pki`, as the chart's: callers verify that
    name, not the address); its API is then called from inside that host.
    """

    def __init__(
        self,
        tmp: Path,
        monitors: Path,
        domain: int,
        *extra: str,
        token: str | None = TOKEN,
        name: str = "edge",
        lab: Any = None,
    ) -> None:
        self.port = free_port()
        self.lab, self.name = lab, name
        self.host = lab.addr[name] if lab is not None else "127.0.0.1"
        self.log = tmp / f"{name}-verdicts.jsonl"
        self.stderr_path = tmp / f"{name}-stderr.log"
        env = ros_env(domain) if lab is None else lab.env()
        env.pop("EDGERV_TOKEN", None)
        if token is not None:
            env["EDGERV_TOKEN"] = token
        self.token = token
        self._stderr = self.stderr_path.open("w")
        wrap = (lambda argv: argv) if lab is None else (lambda argv: lab.command(name, argv))
        if lab is not None:
            certs = shared_pki()
            extra = ("--tls-cert", str(certs.crt), "--tls-key", str(certs.key), *extra)
        self.proc = subprocess.Popen(
            wrap(
                [
                    sys.executable,
                    "-m",
                    "edgerv",
                    "handler",
                    "--name",
                    name,
                    "--monitors",
                    str(monitors),
                    "--listen",
                    f"{self.host}:{self.port}",
                    "--verdict-log",
                    str(self.log),
                    *extra,
                ]
            ),
            env=env,
            stdout=subprocess.DEVNULL,
            stderr=self._stderr,
        )
        self.wait_ready()

    @property
    def stderr(self) -> str:
        return self.stderr_path.read_text()

    def wait_ready(self, timeout: float = 30) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"handler exited {self.proc.returncode}:\n{self.stderr}")
            if " ready: " in self.stderr:
                return
            time.sleep(0.1)
        raise TimeoutError(f"handler not ready:\n{self.stderr}")

    def request(
        self, method: str, path: str, body: str | None = None, token: str | None = "default"
    ) -> tuple[int, Any]:
        token = self.token if token == "default" else token
        if self.lab is not None:
            certs = shared_pki()
            done = self.lab.run(
                self.name,
                [sys.executable, "-c", REQUEST, method, self.host, str(self.port), path,
                 body or "", token or "", str(certs.ca), NAME],
            )  # fmt: skip
            status_line, _, raw = done.stdout.partition("\n")
            try:
                return int(status_line), json.loads(raw)
            except ValueError:
                return int(status_line or 0), raw
        headers = {"Content-Type": "application/yaml"}
        if token is not None:
            headers["Authorization"] = f"Bearer {token}"
        req = urllib.request.Request(
            f"http://127.0.0.1:{self.port}{path}",
            method=method,
            data=body.encode() if body is not None else None,
            headers=headers,
        )
        try:
            with urllib.request.urlopen(req, timeout=30) as resp:
                raw = resp.read().decode()
                status = resp.status
        except urllib.error.HTTPError as err:
            raw, status = err.read().decode(), err.code
        try:
            return status, json.loads(raw)
        except json.JSONDecodeError:
            return status, raw

    def metric(self, name: str, **labels: str) -> float | None:
        _, text = self.request("GET", "/metrics")
        want = ",".join(f'{k}="{v}"' for k, v in labels.items())
        for line in str(text).splitlines():
            key, _, value = line.rpartition(" ")
            if key == (f"{name}{{{want}}}" if labels else name):
                return float(value)
        return None

    def verdicts(self) -> list[dict[str, Any]]:
        if not self.log.exists():
            return []
        return [json.loads(line) for line in self.log.read_text().splitlines()]

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 30) -> int:
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
                raise
        self._stderr.close()
        return self.proc.returncode


def replay_command(monitors: Path, trace: Path, interval: float) -> list[str]:
    """`edgerv replay` of a trace, ``interval`` seconds between messages."""
    return [
        sys.executable,
        "-m",
        "edgerv",
        "replay",
        "--monitors",
        str(monitors),
        str(trace),
        "--interval",
        str(interval),
    ]


def offline_verdicts(monitors: Path, trace: Path) -> list[tuple[str, str, int]]:
    """(monitor, verdict, step) that `edgerv check` gives on the trace, sorted."""
    check = subprocess.run(
        [sys.executable, "-m", "edgerv", "check", str(monitors), str(trace), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    return sorted(
        (m["name"], v["verdict"], v["step"])
        for m in json.loads(check.stdout)["monitors"]
        for v in m["verdicts"]
    )


def check_verdicts(monitors: Path, trace: Path) -> list[tuple[str, str, int, int]]:
    """(monitor, verdict, step, stamp) that `edgerv check` gives on the trace (JSON Lines
    or a bag), sorted; it must exit 0 or 1 (no error)."""
    done = subprocess.run(
        [sys.executable, "-m", "edgerv", "check", str(monitors), str(trace), "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert done.returncode in (0, 1), done.stderr
    return sorted(
        (m["name"], v["verdict"], v["step"], v["stamp"])
        for m in json.loads(done.stdout)["monitors"]
        for v in m["verdicts"]
    )


def live_verdicts(*handlers: HandlerProcess) -> list[tuple[str, str, int]]:
    """(monitor, verdict, step) from the handlers' verdict logs, sorted."""
    return sorted((v["monitor"], v["verdict"], v["step"]) for h in handlers for v in h.verdicts())


def wait_for(predicate: Any, timeout: float = 20, interval: float = 0.1) -> Any:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(interval)
    return predicate()


PUBLISHER = r"""
import json, sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from edgerv.handler.ros.messages import message_class
from edgerv.handler.ros.replay import fill
topic, msg_type, reliability, values, interval = sys.argv[1], sys.argv[2], sys.argv[3], \
    json.loads(sys.argv[4]), float(sys.argv[5])
rclpy.init()
node = rclpy.create_node("test_publisher")
qos = QoSProfile(depth=1000, reliability=getattr(ReliabilityPolicy, reliability.upper()))
pub = node.create_publisher(message_class(msg_type), topic, qos)
deadline = time.monotonic() + 15
while pub.get_subscription_count() == 0 and time.monotonic() < deadline:
    time.sleep(0.05)
time.sleep(0.3)
print("matched" if pub.get_subscription_count() else "unmatched", flush=True)
i = 0
while values or interval < 0:
    v = values.pop(0) if values else {"data": float(i)}
    pub.publish(fill(message_class(msg_type)(), v))
    i += 1
    time.sleep(abs(interval))
time.sleep(0.5)
"""


def publisher(
    domain: int,
    topic: str,
    msg_type: str,
    values: list[dict[str, Any]],
    reliability: str = "reliable",
    interval: float = 0.005,
    forever: bool = False,
) -> subprocess.Popen[str]:
    """A publisher process; with ``forever`` it publishes {"data": i} until killed."""
    return subprocess.Popen(
        [
            sys.executable,
            "-c",
            PUBLISHER,
            topic,
            msg_type,
            reliability,
            json.dumps(values),
            str(-interval if forever else interval),
        ],
        env=ros_env(domain),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def migrate(
    src: HandlerProcess, dst: HandlerProcess, monitor: str, domain: int
) -> subprocess.CompletedProcess[str]:
    """``edgerv migrate`` of ``monitor`` from ``src`` to ``dst``, as a process."""
    env = ros_env(domain, EDGERV_TOKEN=TOKEN)
    return subprocess.run(
        [
            sys.executable,
            "-m",
            "edgerv",
            "migrate",
            "--from",
            f"127.0.0.1:{src.port}",
            "--to",
            f"127.0.0.1:{dst.port}",
            "--monitor",
            monitor,
        ],
        env=env,
        capture_output=True,
        text=True,
        timeout=60,
    )
