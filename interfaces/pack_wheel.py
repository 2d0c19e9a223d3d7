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

Prints the wheel's path. The packing itself is edgerv's
(:func:`edgerv.handler.ros.types.pack_wheel`, which ``edgerv types build --wheel-dir``
packs the robot's own interface packages with), taken from this source tree: standard
library only, edgerv need not be installed. The wheel is reproducible (fixed file times,
sorted entries). Run it with the venv's Python: the wheel is tagged for it.
"""

from __future__ import annotations

import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "handler"))  # this tree's edgerv

from edgerv.handler.ros.types import pack_wheel

SUMMARY = "edgerv's ROS 2 interfaces (edgerv_msgs), built by interfaces/build.sh"


def main(argv: list[str]) -> int:
    if len(argv) < 4:
        print(__doc__, file=sys.stderr)
        return 2
    stage, out, dist, version, *requires = argv
    try:
        wheel = pack_wheel(Path(stage), Path(out), dist, version, requires, SUMMARY)
    except ValueError as exc:
        print(f"pack_wheel.py: {exc}", file=sys.stderr)
        return 1
    print(wheel)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
