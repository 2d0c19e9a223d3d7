"""Pack an ament install prefix (what ``cmake --install`` wrote) into a wheel laid out like
the ros-jazzy-* wheels on PyPI, so that pip installs it into a venv the same way:

- ``<prefix>/lib/pythonX.Y/site-packages/*`` goes to the wheel's root (site-packages:
  the generated Python package and its extension modules);
- everything else (``lib/*.so``, ``share/``, ``include/``) goes to
  ``<name>-<version>.data/data/``, which pip installs relative to the venv's prefix: the
  libraries land in ``<venv>/lib``, where ros_wheels_bootstrapper points LD_LIBRARY_PATH,
  and ``share/edgerv_msgs`` (the .msg files, the ament index) in ``<venv>/share``, where
  ament_index and edgerv's own type reader look.

usage: python pack_wheel.py STAGE OUT_DIR DIST_NAME VERSION [REQUIREMENT...]

Prints the wheel's path. Standard library only; the wheel is reproducible (fixed file
times, sorted entries). Run it with the venv's Python: the wheel is tagged for it.
"""

from __future__ import annotations

import base64
import hashlib
import sys
import sysconfig
import zipfile
from pathlib import Path

FIXED_TIME = (2020, 1, 1, 0, 0, 0)  # zip entries' time: the same sources, the same wheel


def record_hash(data: bytes) -> str:
    """A RECORD line's hash: sha256, urlsafe base64 without padding (PEP 376/427)."""
    digest = hashlib.sha256(data).digest()
    return "sha256=" + base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def collect(stage: Path, data_dir: str) -> tuple[list[tuple[str, bytes, int]], set[str]]:
    """The install tree's files as (name in the wheel, bytes, mode), and the top-level
    names of what goes to site-packages."""
    site = ("lib", f"python{sys.version_info.major}.{sys.version_info.minor}", "site-packages")
    entries: list[tuple[str, bytes, int]] = []
    top_level: set[str] = set()
    for path in sorted(p for p in stage.rglob("*") if p.is_file()):
        parts = path.relative_to(stage).parts
        if "__pycache__" in parts or any(p.endswith(".egg-info") for p in parts):
            continue  # bytecode is compiled at install; an egg-info would be a second dist
        if parts[: len(site)] == site:
            inner = parts[len(site) :]
            name = "/".join(inner)
            top_level.add(inner[0])
        else:
            name = f"{data_dir}/{'/'.join(parts)}"
        entries.append((name, path.read_bytes(), path.stat().st_mode & 0o777))
    return entries, top_level


def main(argv: list[str]) -> int:
    if len(argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    stage, out, dist, version, *requires = argv
    stage_dir = Path(stage)
    if not (stage_dir / "share").is_dir():
        print(f"pack_wheel.py: {stage_dir} is not an install prefix (no share/)", file=sys.stderr)
        return 1
    norm = dist.replace("-", "_")
    tag_py = f"cp{sys.version_info.major}{sys.version_info.minor}"
    platform = sysconfig.get_platform().replace("-", "_").replace(".", "_")
    tag = f"{tag_py}-{tag_py}-{platform}"
    distinfo = f"{norm}-{version}.dist-info"

    entries, top_level = collect(stage_dir, f"{norm}-{version}.data/data")
    if not top_level:
        print(f"pack_wheel.py: no Python package under {stage_dir}/lib", file=sys.stderr)
        return 1
    metadata = [
        "Metadata-Version: 2.1",
        f"Name: {dist}",
        f"Version: {version}",
        "Summary: edgerv's ROS 2 interfaces (edgerv_msgs), built by interfaces/build.sh",
        "License: Apache-2.0",
        *(f"Requires-Dist: {r}" for r in requires),
    ]
    meta_files = {
        f"{distinfo}/METADATA": "\n".join(metadata) + "\n",
        f"{distinfo}/WHEEL": (
            "Wheel-Version: 1.0\nGenerator: edgerv interfaces/pack_wheel.py\n"
            f"Root-Is-Purelib: false\nTag: {tag}\n"
        ),
        f"{distinfo}/top_level.txt": "\n".join(sorted(top_level)) + "\n",
    }
    entries += [(name, text.encode(), 0o644) for name, text in meta_files.items()]

    Path(out).mkdir(parents=True, exist_ok=True)
    wheel = Path(out) / f"{norm}-{version}-{tag}.whl"
    record = []
    with zipfile.ZipFile(wheel, "w", compression=zipfile.ZIP_DEFLATED) as zf:
        for name, blob, mode in entries:
            info = zipfile.ZipInfo(name, date_time=FIXED_TIME)
            info.external_attr = (0o100000 | mode) << 16  # a regular file, its permissions
            info.compress_type = zipfile.ZIP_DEFLATED
            zf.writestr(info, blob)
            record.append(f"{name},{record_hash(blob)},{len(blob)}")
        record.append(f"{distinfo}/RECORD,,")
        info = zipfile.ZipInfo(f"{distinfo}/RECORD", date_time=FIXED_TIME)
        info.external_attr = 0o100644 << 16
        zf.writestr(info, "\n".join(record) + "\n")
    print(wheel)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
