"""Test hosts on this machine: network namespaces joined by a user-space delayed link.

``Lab(delay_ms=20)`` makes two hosts, ``edge`` and ``cloud``, each a network
namespace with loopback and one TUN device; ``linkdelay.py`` carries every IP
packet between the two devices ``delay_ms`` later (this kernel has no netem).
Addresses: ``10.77.N.1`` (edge) and ``10.77.N.2`` (cloud), N from the lab's id.
Processes started with :meth:`Lab.popen` run inside a host with a ROS 2
environment that reaches the other host only through the link: Fast DDS over
UDPv4 only (no shared memory, which would bypass the link), unicast discovery
to the two addresses (``ROS_STATIC_PEERS``).

Needs root (namespaces, TUN). Everything is removed on :meth:`Lab.close`, and a
lab left behind by a killed run (its creator process is gone) is removed by the
next one.
"""

from __future__ import annotations

import json
import os
import re
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

LINKDELAY = Path(__file__).with_name("linkdelay.py")
_NS = re.compile(r"^erv(\d+)-(edge|cloud)$")


def available() -> str | None:
    """Why labs cannot be made here, or None when they can."""
    if os.geteuid() != 0:
        return "needs root (network namespaces and TUN devices)"
    if not Path("/dev/net/tun").exists():
        return "no /dev/net/tun"
    try:
        subprocess.run(["ip", "netns", "list"], check=True, capture_output=True)
    except (OSError, subprocess.CalledProcessError) as exc:
        return f"ip netns does not work: {exc}"
    return None


def _ip(*args: str, check: bool = True) -> None:
    subprocess.run(["ip", *args], check=check, capture_output=True, text=True)


def remove_stale() -> None:
    """Delete the namespaces of labs whose creator process has died."""
    out = subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
    for line in out.splitlines():
        m = _NS.match(line.split()[0]) if line.strip() else None
        if m and not Path(f"/proc/{m.group(1)}").exists():
            _ip("netns", "del", line.split()[0], check=False)


class Lab:
    def __init__(self, delay_ms: float = 20.0, domain: int = 42) -> None:
        remove_stale()
        self.id = os.getpid()
        self.delay_ms = delay_ms
        self.domain = domain
        net = self.id % 250
        self.hosts = {"edge": f"erv{self.id}-edge", "cloud": f"erv{self.id}-cloud"}
        self.addr = {"edge": f"10.77.{net}.1", "cloud": f"10.77.{net}.2"}
        self.procs: list[subprocess.Popen[Any]] = []
        self.link_stats: dict[str, Any] | None = None
        devs = {"edge": f"erv{self.id % 100000}e", "cloud": f"erv{self.id % 100000}c"}
        try:
            for ns in self.hosts.values():
                _ip("netns", "del", ns, check=False)
                _ip("netns", "add", ns)
                _ip("-n", ns, "link", "set", "lo", "up")
            self.link = subprocess.Popen(
                [sys.executable, str(LINKDELAY), devs["edge"], devs["cloud"], str(delay_ms)],
                stdout=subprocess.PIPE,
                text=True,
            )
            assert self.link.stdout is not None
            if self.link.stdout.readline().strip() != "ready":
                raise RuntimeError("linkdelay did not start")
            for host, dev in devs.items():
                ns = self.hosts[host]
                _ip("link", "set", dev, "netns", ns)
                _ip("-n", ns, "addr", "add", f"{self.addr[host]}/24", "dev", dev)
                _ip("-n", ns, "link", "set", dev, "up", "multicast", "on")
        except BaseException:
            self.close()
            raise

    def env(self, **extra: str) -> dict[str, str]:
        env = dict(os.environ)
        env.pop("ROS_AUTOMATIC_DISCOVERY_RANGE", None)
        env.update(
            ROS_DOMAIN_ID=str(self.domain),
            ROS_AUTOMATIC_DISCOVERY_RANGE="SUBNET",
            ROS_STATIC_PEERS=";".join(self.addr.values()),
            FASTDDS_BUILTIN_TRANSPORTS="UDPv4",
            PYTHONUNBUFFERED="1",
        )
        env.update(extra)
        return env

    def command(self, host: str, argv: Sequence[str]) -> list[str]:
        return ["ip", "netns", "exec", self.hosts[host], *argv]

    def popen(self, host: str, argv: Sequence[str], **kwargs: Any) -> subprocess.Popen[Any]:
        kwargs.setdefault("env", self.env())
        proc = subprocess.Popen(self.command(host, argv), **kwargs)
        self.procs.append(proc)
        return proc

    def run(
        self, host: str, argv: Sequence[str], **kwargs: Any
    ) -> subprocess.CompletedProcess[Any]:
        kwargs.setdefault("env", self.env())
        kwargs.setdefault("capture_output", True)
        kwargs.setdefault("text", True)
        return subprocess.run(self.command(host, argv), **kwargs)

    def round_trip_ms(self, host: str = "edge", port: int = 7, samples: int = 5) -> list[float]:
        """TCP connect times from ``host`` to the other one (one round trip each).

        Nothing listens on the port: the peer's RST answers the SYN, which is a
        full round trip through the link.
        """
        other = self.addr["cloud" if host == "edge" else "edge"]
        code = (
            "import socket, time, json\n"
            "out = []\n"
            f"for _ in range({samples}):\n"
            "    s = socket.socket(); t = time.perf_counter()\n"
            f"    try: s.connect(({other!r}, {port}))\n"
            "    except OSError: pass\n"
            "    out.append((time.perf_counter() - t) * 1000); s.close()\n"
            "print(json.dumps(out))\n"
        )
        done = self.run(host, [sys.executable, "-c", code], check=True, timeout=30)
        return [float(x) for x in json.loads(done.stdout)]

    def close(self) -> None:
        for proc in self.procs:
            if proc.poll() is None:
                proc.terminate()
        deadline = time.monotonic() + 10
        for proc in self.procs:
            try:
                proc.wait(timeout=max(0.1, deadline - time.monotonic()))
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        link = getattr(self, "link", None)
        if link is not None and link.poll() is None:
            link.terminate()
            try:
                out, _ = link.communicate(timeout=5)
                self.link_stats = json.loads(out.strip().splitlines()[-1]) if out.strip() else None
            except (subprocess.TimeoutExpired, ValueError):
                link.kill()
                link.wait()
        for ns in self.hosts.values():
            _ip("netns", "del", ns, check=False)

    def __enter__(self) -> Lab:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
