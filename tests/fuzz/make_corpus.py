"""Write the fuzz targets' seed corpus: real inputs each target's fuzzer starts from.

    python tests/fuzz/make_corpus.py    # rewrites tests/fuzz/corpus/{cdr,bundle}/

CDR seeds: for each reader of ``fuzz_cdr.READERS``, its index byte and a message of
its type as rosbags serializes it (the bytes a publisher sends). Bundle seeds: real
snapshots of each monitor of ``fuzz_bundle.ASSERTIONS``, as a bundle (entry 0), as a
frame (entries 1 and 2, and 2 swollen) and as a header and a body (entry 3). API seeds:
requests of each call, as ``fuzz_api`` reads them (a byte for the reads' size, then the
bytes sent), a real bundle for its receiving monitor among them::

    python tests/fuzz/make_corpus.py api    # only tests/fuzz/corpus/api/
"""

from __future__ import annotations

import hashlib
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))

import fuzz_api  # noqa: E402
import fuzz_bundle  # noqa: E402
import fuzz_cdr  # noqa: E402


def messages() -> dict[str, Any]:
    from edgerv.core.msgtypes import typestore

    t = typestore().types
    g = "geometry_msgs/msg/"
    header = t["std_msgs/msg/Header"](t["builtin_interfaces/msg/Time"](12, 345), "base")
    vec = t[g + "Vector3"](0.5, -1.0, 2.0)
    pose = t[g + "Pose"](t[g + "Point"](1.0, 2.0, 3.0), t[g + "Quaternion"](0.0, 0.0, 0.0, 1.0))
    cov = np.arange(36, dtype=np.float64)
    kv = t["diagnostic_msgs/msg/KeyValue"]
    status = t["diagnostic_msgs/msg/DiagnosticStatus"]
    return {
        "sensor_msgs/msg/LaserScan": t["sensor_msgs/msg/LaserScan"](
            header,
            -1.5,
            1.5,
            0.01,
            0.0,
            0.1,
            0.1,
            30.0,
            np.array([1.0, 2.5, 3.0, 0.5], np.float32),
            np.array([7, 8, 9, 10], np.float32),
        ),
        "nav_msgs/msg/Odometry": t["nav_msgs/msg/Odometry"](
            header,
            "base_link",
            t[g + "PoseWithCovariance"](pose, cov),
            t[g + "TwistWithCovariance"](t[g + "Twist"](vec, vec), cov),
        ),
        "std_msgs/msg/String": t["std_msgs/msg/String"]("AUTO"),
        "geometry_msgs/msg/PolygonInstance": t[g + "PolygonInstance"](
            t[g + "Polygon"]([t[g + "Point32"](1.0, 2.0, 0.0), t[g + "Point32"](3.0, 4.0, 0.0)]),
            42,
        ),
        "sensor_msgs/msg/JointState": t["sensor_msgs/msg/JointState"](
            header, ["hip", "knee", "ankle"], *(np.array([0.1, 0.2, 0.3]) for _ in range(3))
        ),
        "diagnostic_msgs/msg/DiagnosticArray": t["diagnostic_msgs/msg/DiagnosticArray"](
            header,
            [status(0, "motor", "ok", "hw1", [kv("temp", "40"), kv("load", "0.3")])],
        ),
    }


def write(directory: Path, data: bytes) -> None:
    (directory / hashlib.sha1(data).hexdigest()).write_bytes(data)


def main() -> None:
    from edgerv.core.handoff import bundle, encode
    from edgerv.core.msgtypes import typestore
    from edgerv.core.pipeline import MonitorRuntime

    cdr_dir, bundle_dir = HERE / "corpus" / "cdr", HERE / "corpus" / "bundle"
    for d in (cdr_dir, bundle_dir):
        d.mkdir(parents=True, exist_ok=True)
        for old in d.iterdir():
            old.unlink()
    store, msgs = typestore(), messages()
    for i, (msg_type, _) in enumerate(fuzz_cdr.READERS):
        write(cdr_dir, bytes([i]) + bytes(store.serialize_cdr(msgs[msg_type], msg_type)))
    fuzz_bundle.load()
    for i, monitor in enumerate(fuzz_bundle._monitors):
        rt = MonitorRuntime(monitor)
        rt.holding = True
        for stamp, seq, updates in fuzz_bundle.events(i, 40, 100):
            rt.offer(stamp, seq, updates)
        frame = encode(rt.snapshot(cut=140, epoch=7))
        write(bundle_dir, bytes([0, i]) + bundle([frame]))
        write(bundle_dir, bytes([1, i]) + frame)
        write(bundle_dir, bytes([2, i]) + frame + frame)
        write(bundle_dir, bytes([2, i + 4 * 6]) + frame)  # swollen (fuzz_bundle.SWELL)
        size = int.from_bytes(frame[4:8], "big")
        write(bundle_dir, bytes([3, i]) + size.to_bytes(2, "big") + frame[12:])


def api_requests() -> list[bytes]:
    """One request of each call (and a few pipelined, chunked), as a client sends them."""
    from edgerv.core.handoff import bundle, encode
    from edgerv.core.pipeline import MonitorRuntime

    fuzz_api.load()
    rt = MonitorRuntime(fuzz_api._state["monitors"]["n"])
    rt.holding = True
    for stamp, seq, updates in fuzz_bundle.events(3, 40, 100):
        rt.offer(stamp, seq, updates)
    adoptable = bundle([encode(rt.snapshot(cut=150, epoch=fuzz_api.EPOCH))])

    def request(method: str, path: str, body: bytes = b"", token: bool = True) -> bytes:
        auth = f"Authorization: Bearer {fuzz_api.TOKEN}\r\n" if token else ""
        length = f"Content-Length: {len(body)}\r\n" if method in ("POST", "PUT") else ""
        return f"{method} {path} HTTP/1.1\r\nHost: edge\r\n{auth}{length}\r\n".encode() + body

    def step(name: str, **fields: object) -> bytes:
        body = {"epoch": 9, "monitors": ["m"], **fields}
        return request("POST", f"/v1/handoff/{name}", json.dumps(body).encode())

    document = fuzz_api.DOCUMENT.replace("NAME", "q").encode()
    chunked = (
        f"POST /v1/monitors HTTP/1.1\r\nHost: e\r\nAuthorization: Bearer {fuzz_api.TOKEN}\r\n"
        "Transfer-Encoding: chunked\r\n\r\n"
    ).encode() + b"".join(b"%x\r\n%s\r\n" % (len(p), p) for p in (document[:50], document[50:]))
    return [
        request("GET", "/healthz", token=False),
        request("GET", "/metrics", token=False),
        request("GET", "/v1/monitors") + request("GET", "/v1/monitors/m")
        + request("GET", "/v1/load"),
        request("GET", "/v1/monitors", token=False),
        request("POST", "/v1/monitors", document),
        chunked + b"0\r\n\r\n",
        request("PUT", "/v1/monitors/q", document) + request("DELETE", "/v1/monitors/q"),
        request("POST", "/v1/monitors/m/deactivate") + request("POST", "/v1/monitors/m/activate"),
        step("hold", peer="http://127.0.0.1:1") + step("release", cuts={"m": 200}, grace=0.0)
        + step("commit"),
        step("hold") + step("abort"),
        request("POST", "/v1/handoff/cut", json.dumps({"epoch": 7, "monitors": ["n"]}).encode()),
        request("POST", f"/v1/handoff/adopt?epoch={fuzz_api.EPOCH}", adoptable),
        request("POST", "/v1/handoff/adopt?epoch=8", adoptable),
    ]  # fmt: skip


def api_seeds() -> None:
    api_dir = HERE / "corpus" / "api"
    api_dir.mkdir(parents=True, exist_ok=True)
    for old in api_dir.iterdir():
        old.unlink()
    for i, data in enumerate(api_requests()):
        write(api_dir, bytes([0 if i % 3 else 7]) + data)


if __name__ == "__main__":
    if sys.argv[1:] == ["api"]:
        api_seeds()
    else:
        main()
        api_seeds()
