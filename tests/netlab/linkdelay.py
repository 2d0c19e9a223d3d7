"""A user-space link with delay between two TUN devices (this kernel has no netem).

Run as root: ``python linkdelay.py NAME_A NAME_B DELAY_MS``. It creates the TUN
devices NAME_A and NAME_B in the current network namespace, prints ``ready``
and waits; the caller moves each device into its namespace and gives it an
address (the open file descriptors keep working across the move). Each IP
packet read from one device is written to the other ``DELAY_MS`` later, in
order: a point-to-point link with that one-way delay and no loss. On SIGTERM
it prints the packets and bytes it carried each way, as JSON, and exits.
"""

from __future__ import annotations

import fcntl
import heapq
import json
import os
import select
import signal
import struct
import sys
import time

TUNSETIFF = 0x400454CA
IFF_TUN = 0x0001
IFF_NO_PI = 0x1000


def open_tun(name: str) -> int:
    fd = os.open("/dev/net/tun", os.O_RDWR | os.O_NONBLOCK)
    fcntl.ioctl(fd, TUNSETIFF, struct.pack("16sH", name.encode(), IFF_TUN | IFF_NO_PI))
    return fd


def main() -> int:
    a_name, b_name, delay_ms = sys.argv[1], sys.argv[2], float(sys.argv[3])
    delay = delay_ms / 1000.0
    a, b = open_tun(a_name), open_tun(b_name)
    peer = {a: b, b: a}
    counts = {a_name: [0, 0], b_name: [0, 0]}  # packets, bytes read from each side
    label = {a: a_name, b: b_name}
    stopping = []
    signal.signal(signal.SIGTERM, lambda *_: stopping.append(True))
    signal.signal(signal.SIGINT, lambda *_: stopping.append(True))
    print("ready", flush=True)
    queue: list[tuple[float, int, int, bytes]] = []  # (due, seq, out fd, packet)
    seq = lost = 0
    poller = select.poll()
    for fd in (a, b):
        poller.register(fd, select.POLLIN)
    while not stopping:
        now = time.monotonic()
        while queue and queue[0][0] <= now:
            _, _, out, packet = heapq.heappop(queue)
            try:
                os.write(out, packet)
            except OSError:  # a device down (being moved) or its queue full: packet lost
                lost += 1
        wait = max(0.0, queue[0][0] - now) if queue else 0.2
        try:
            ready = poller.poll(wait * 1000.0)
        except InterruptedError:
            continue
        now = time.monotonic()
        for fd, _ in ready:
            for _ in range(64):
                try:
                    packet = os.read(fd, 65536)
                except (BlockingIOError, OSError):
                    break
                counts[label[fd]][0] += 1
                counts[label[fd]][1] += len(packet)
                seq += 1
                heapq.heappush(queue, (now + delay, seq, peer[fd], packet))
    carried = {k: {"packets": p, "bytes": n} for k, (p, n) in counts.items()}
    print(json.dumps({"from": carried, "lost": lost}))
    return 0


if __name__ == "__main__":
    sys.exit(main())
