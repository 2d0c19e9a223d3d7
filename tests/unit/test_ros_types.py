"""The robot's own message types for the live handler (edgerv.handler.ros.types), without
building: what a package is made of and uses, the plan and its digests, the project files
a build is given, the cache's place, the hints when a type cannot be had, the wheels.
A real rosidl build, and a handler and a publisher on the built types:
tests/integration/test_own_types.py."""

from __future__ import annotations

import hashlib
import io
import json
import os
import re
import subprocess
import sys
import zipfile
from base64 import urlsafe_b64encode
from collections.abc import Callable, Iterator
from pathlib import Path

import pytest

from edgerv.handler.ros import types as ros_types
from edgerv.handler.ros.types import (
    MissingTools,
    TypesError,
    cache_dir,
    discover,
    names_used,
    pack_wheel,
    plan,
    read_package,
)
from kit.cli import edgerv

ROOT = Path(__file__).resolve().parents[2]

STATE = """\
# a robot's state
std_msgs/Header header
float64 battery
string mode
string<=8 short_mode
geometry_msgs/Point target   # a standard package
Wheel[] wheels               # this package
common_msgs/Vec2[2] corners  # another package of the user's
int32[<=4] codes
uint8 MODE_AUTO=1
"""
WHEEL = "float32 rpm\nbool slipping\ncommon_msgs/msg/Vec2 force\n"
VEC2 = "float64 x\nfloat64 y\n"


def write_pkg(top: Path, name: str, files: dict[str, str], xml_name: str | None = None) -> Path:
    root = top / name
    for rel, text in files.items():
        (root / rel).parent.mkdir(parents=True, exist_ok=True)
        (root / rel).write_text(text)
    if xml_name is not None:
        (root / "package.xml").write_text(
            f"<package format='3'><name>{xml_name}</name><version>1.2.3</version></package>"
        )
    return root


@pytest.fixture
def defs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """my_robot_msgs (State, Wheel) and common_msgs (Vec2) under $EDGERV_MSG_PATH."""
    top = tmp_path / "defs"
    write_pkg(top, "my_robot_msgs", {"msg/State.msg": STATE, "msg/Wheel.msg": WHEEL})
    write_pkg(top, "common_msgs", {"msg/Vec2.msg": VEC2})
    monkeypatch.setenv("EDGERV_MSG_PATH", str(top))
    monkeypatch.setenv(ros_types.CACHE_ENV, str(tmp_path / "cache"))
    return top


def test_the_packages_a_definition_uses() -> None:
    assert names_used("my_robot_msgs", STATE) == {
        "std_msgs",
        "geometry_msgs",
        "my_robot_msgs",
        "common_msgs",
    }
    # (a bare Header is the package's own, as rosidl reads it)
    assert names_used("p", "Header header\ntime t\nduration d\n") == {"p", "builtin_interfaces"}
    service = "int32 a\n---\nq_msgs/Q q\n"
    assert names_used("p", service) == {"q_msgs"}
    action = "Goal g\n---\nbool ok\n---\nfloat32 progress\n"
    assert names_used("p", action) == {"p"}
    assert names_used("p", "# only a comment\n\nstring s 'x # not a comment'\n") == set()


def test_a_package_is_its_interface_files_and_the_packages_they_name(defs: Path) -> None:
    package = read_package(defs / "my_robot_msgs")
    assert package.name == "my_robot_msgs"
    assert [rel for rel, _ in package.files] == ["msg/State.msg", "msg/Wheel.msg"]
    assert package.uses == ("common_msgs", "geometry_msgs", "std_msgs")
    assert package.version == "0.0.0"
    with pytest.raises(TypesError, match="no interface definitions"):
        read_package(defs)


def test_discover_finds_packages_by_their_package_xml_name_in_a_workspace(tmp_path: Path) -> None:
    ws = tmp_path / "ws"
    write_pkg(ws / "src" / "repo", "robot_interfaces", {"msg/A.msg": "int32 a\n"}, "robot_msgs")
    write_pkg(ws / "src", "other_msgs", {"srv/Do.srv": "int32 a\n---\nbool ok\n"})
    # a colcon build directory holds copies that are not searched
    write_pkg(ws / "build", "robot_msgs", {"msg/A.msg": "int32 b\n"})
    found = discover([ws])
    assert found == {
        "robot_msgs": ws / "src" / "repo" / "robot_interfaces",
        "other_msgs": ws / "src" / "other_msgs",
    }
    assert read_package(found["robot_msgs"]).version == "1.2.3"
    assert discover([ws / "src" / "other_msgs"]) == {"other_msgs": ws / "src" / "other_msgs"}
    # the same package twice: one is enough when they agree; an error when they differ
    write_pkg(ws / "install" / "share", "other_msgs", {"srv/Do.srv": "int32 a\n---\nbool ok\n"})
    assert set(discover([ws])) == {"robot_msgs", "other_msgs"}
    write_pkg(ws / "install" / "share", "robot_msgs", {"msg/A.msg": "int64 a\n"})
    with pytest.raises(TypesError, match="two packages named robot_msgs"):
        discover([ws])
    with pytest.raises(TypesError, match="no such directory"):
        discover([tmp_path / "nowhere"])


def test_the_plan_builds_the_users_packages_it_uses_first_and_uses_installed_ones(
    defs: Path,
) -> None:
    steps = plan("my_robot_msgs")
    assert [s.name for s in steps] == ["common_msgs", "my_robot_msgs"]
    robot = steps[-1]
    assert robot.customs == ("common_msgs",)
    assert set(robot.externals) == {"geometry_msgs", "std_msgs"}  # the venv's wheels
    assert robot.package.root == (defs / "my_robot_msgs").resolve()


def test_a_digest_follows_the_definitions_and_those_of_the_packages_used(defs: Path) -> None:
    first = {s.name: s.digest for s in plan("my_robot_msgs")}
    assert first == {s.name: s.digest for s in plan("my_robot_msgs")}  # stable
    (defs / "common_msgs" / "msg" / "Vec2.msg").write_text(VEC2 + "float64 z\n")
    second = {s.name: s.digest for s in plan("my_robot_msgs")}
    assert second["common_msgs"] != first["common_msgs"]
    assert second["my_robot_msgs"] != first["my_robot_msgs"]  # it embeds Vec2: rebuilt
    (defs / "my_robot_msgs" / "msg" / "Wheel.msg").write_text(WHEEL + "# a comment\n")
    third = {s.name: s.digest for s in plan("my_robot_msgs")}
    assert third["common_msgs"] == second["common_msgs"]
    assert third["my_robot_msgs"] != second["my_robot_msgs"]


def test_a_package_that_is_nowhere_says_where_it_was_looked_for(defs: Path) -> None:
    (defs / "my_robot_msgs" / "msg" / "Wheel.msg").write_text("nav2_things/Thing t\n")
    with pytest.raises(TypesError) as info:
        plan("my_robot_msgs")
    text = str(info.value)
    assert "nav2_things (used by my_robot_msgs)" in text
    assert f"$EDGERV_MSG_PATH ({defs})" in text
    assert "point EDGERV_MSG_PATH at the directory that holds nav2_things/msg/" in text
    # a released package of ROS 2's own: its wheel first
    (defs / "my_robot_msgs" / "msg" / "Wheel.msg").write_text("visualization_msgs/Marker m\n")
    with pytest.raises(
        TypesError, match=r"ROS 2 package: pip install ros-jazzy-visualization-msgs"
    ):
        plan("my_robot_msgs")


def test_packages_that_use_each_other_are_refused(defs: Path) -> None:
    (defs / "common_msgs" / "msg" / "Vec2.msg").write_text("my_robot_msgs/Wheel w\n")
    with pytest.raises(TypesError, match="my_robot_msgs -> common_msgs -> my_robot_msgs"):
        plan("my_robot_msgs")


def test_the_project_a_build_is_given(defs: Path) -> None:
    robot = plan("my_robot_msgs")[-1]
    files = ros_types._project_files(robot)
    xml, cmake = files["package.xml"], files["CMakeLists.txt"]
    assert "<name>my_robot_msgs</name>" in xml
    assert "<member_of_group>rosidl_interface_packages</member_of_group>" in xml
    for dep in ("common_msgs", "geometry_msgs", "std_msgs"):
        assert f"<depend>{dep}</depend>" in xml
    assert "project(my_robot_msgs)" in cmake
    assert '"msg/State.msg"\n  "msg/Wheel.msg"' in cmake
    assert "DEPENDENCIES common_msgs geometry_msgs std_msgs" in cmake
    # the fix for the PyPI wheels' CMake exports: the same as edgerv_msgs'
    ours = (ROOT / "interfaces" / "edgerv_msgs" / "CMakeLists.txt").read_text()
    fix = ours[ours.index("find_package(Python3 REQUIRED") :]
    fix = "\n".join(line for line in fix.splitlines() if "message(STATUS" not in line)
    assert fix.strip() in cmake
    common = ros_types._project_files(plan("common_msgs")[-1])["CMakeLists.txt"]
    assert "DEPENDENCIES" not in common


def test_the_build_requirements_are_those_of_interfaces_build_sh() -> None:
    script = (ROOT / "interfaces" / "build.sh").read_text()
    block = script[
        script.index("BUILD_REQS=(") : script.index("\n)\n", script.index("BUILD_REQS=("))
    ]
    listed = re.findall(r"^\s+([a-z0-9-]+)", block, re.M)
    assert tuple(listed) == ros_types.BUILD_REQUIREMENTS


def test_the_cache_is_the_flag_else_the_environment_else_the_users_cache(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.delenv(ros_types.CACHE_ENV, raising=False)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert cache_dir() == tmp_path / "xdg" / "edgerv" / "types"
    monkeypatch.delenv("XDG_CACHE_HOME")
    monkeypatch.setenv("HOME", str(tmp_path / "home"))
    assert cache_dir() == tmp_path / "home" / ".cache" / "edgerv" / "types"
    monkeypatch.setenv(ros_types.CACHE_ENV, str(tmp_path / "env"))
    assert cache_dir() == tmp_path / "env"
    assert cache_dir(str(tmp_path / "flag")) == tmp_path / "flag"
    assert cache_dir("none") is None
    monkeypatch.setenv(ros_types.CACHE_ENV, "none")
    assert cache_dir() is None


@pytest.fixture
def no_tools(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """A machine without cmake, make and compilers (an empty PATH)."""
    empty = tmp_path / "empty-bin"
    empty.mkdir()
    monkeypatch.setenv("PATH", str(empty))
    monkeypatch.delenv("CC", raising=False)
    monkeypatch.delenv("CXX", raising=False)


def test_missing_tools_are_each_named_with_how_to_install_them(no_tools: None) -> None:
    with pytest.raises(MissingTools) as info:
        ros_types.check_tools()
    text = str(info.value)
    for wanted in ("no cmake", "apt-get install cmake", "no make", "no C compiler", "g++"):
        assert wanted in text


def test_without_tools_the_handler_says_how_to_build_ahead(defs: Path, no_tools: None) -> None:
    with pytest.raises(TypesError) as info:
        ros_types.message_class("my_robot_msgs/msg/State")
    text = str(info.value)
    assert text.startswith("message type my_robot_msgs/msg/State is not installed in this handler")
    assert "no cmake (Debian: apt-get install cmake)" in text
    # both packages to build are in one directory: it is named (common_msgs is needed too)
    assert f"`edgerv types build {defs.resolve()} --wheel-dir WHEELS`" in text
    with pytest.raises(TypesError, match=rf"`edgerv types build {defs.resolve()}/common_msgs "):
        ros_types.message_class("common_msgs/msg/Vec2")
    assert "pip install --no-deps WHEELS/*.whl" in text
    assert not (defs.parent / "cache").exists() or not any((defs.parent / "cache").iterdir())


def test_a_type_nowhere_gets_the_hint_of_where_to_put_it(defs: Path) -> None:
    with pytest.raises(ImportError) as info:
        ros_types.message_class("their_msgs/msg/Thing")
    text = str(info.value)
    assert "their_msgs is not installed here, and no definition of it was found" in text
    assert "point EDGERV_MSG_PATH at the directory that holds their_msgs/msg/" in text
    assert "a colcon workspace's src/, or its install/their_msgs/share" in text


def test_a_type_missing_from_an_installed_package_says_so_with_a_close_name(defs: Path) -> None:
    with pytest.raises(TypesError, match=r"std_msgs installed here has no msg/Bol: did you mean "):
        ros_types.message_class("std_msgs/msg/Bol")


def test_with_the_cache_off_nothing_is_built(defs: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv(ros_types.CACHE_ENV, "none")
    with pytest.raises(TypesError, match=r"building message types is off here"):
        ros_types.message_class("my_robot_msgs/msg/State")


def test_a_directory_named_like_the_package_is_not_taken_for_it_installed(
    defs: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.syspath_prepend(str(defs))  # (the handler run from the definitions' directory)
    assert ros_types._module_prefix("my_robot_msgs") is None
    assert ros_types._module_prefix("std_msgs") is not None


def test_a_wheel_is_laid_out_as_pypis_ros_wheels(tmp_path: Path) -> None:
    stage = tmp_path / "prefix"
    site = stage / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}" / "site-packages"
    files = {
        site / "my_msgs" / "__init__.py": b"",
        site / "my_msgs" / "msg" / "_state.py": b"class State: ...\n",
        site / "my_msgs" / "__pycache__" / "x.pyc": b"\0",
        stage / "lib" / "libmy_msgs__rosidl_generator_c.so": b"\x7fELF",
        stage / "share" / "my_msgs" / "msg" / "State.msg": b"int32 a\n",
    }
    for path, blob in files.items():
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(blob)
    wheel = pack_wheel(stage, tmp_path / "out", "my-msgs", "1.0+src.abc", ["ros-std-msgs~=5.3"])
    again = pack_wheel(stage, tmp_path / "again", "my-msgs", "1.0+src.abc", ["ros-std-msgs~=5.3"])
    assert wheel.read_bytes() == again.read_bytes()  # reproducible
    assert wheel.name == f"my_msgs-1.0+src.abc-{ros_types.wheel_tag()}.whl"
    with zipfile.ZipFile(wheel) as zf:
        names = set(zf.namelist())
        data = "my_msgs-1.0+src.abc.data/data"
        assert {"my_msgs/__init__.py", "my_msgs/msg/_state.py"} <= names  # site-packages
        assert f"{data}/lib/libmy_msgs__rosidl_generator_c.so" in names
        assert f"{data}/share/my_msgs/msg/State.msg" in names
        assert not any("__pycache__" in n for n in names)
        meta = zf.read("my_msgs-1.0+src.abc.dist-info/METADATA").decode()
        assert "Requires-Dist: ros-std-msgs~=5.3" in meta
        for line in zf.read("my_msgs-1.0+src.abc.dist-info/RECORD").decode().splitlines():
            name, digest, size = line.split(",")
            if digest:
                blob = zf.read(name)
                want = urlsafe_b64encode(hashlib.sha256(blob).digest()).rstrip(b"=").decode()
                assert digest == f"sha256={want}" and int(size) == len(blob)
    with pytest.raises(ValueError, match="not an install prefix"):
        pack_wheel(tmp_path / "out", tmp_path / "x", "d", "1")


def test_interfaces_pack_wheel_py_packs_with_the_same_code(tmp_path: Path) -> None:
    stage = tmp_path / "prefix"
    py = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    (stage / "lib" / py / "site-packages" / "m").mkdir(parents=True)
    (stage / "lib" / py / "site-packages" / "m" / "__init__.py").write_text("")
    (stage / "share" / "m").mkdir(parents=True)
    done = subprocess.run(
        [sys.executable, str(ROOT / "interfaces" / "pack_wheel.py"), str(stage),
         str(tmp_path / "out"), "m", "1.0", "ros-x~=1"],
        capture_output=True, text=True, timeout=60, check=False,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr
    wheel = Path(done.stdout.strip())
    with zipfile.ZipFile(io.BytesIO(wheel.read_bytes())) as zf:
        meta = zf.read("m-1.0.dist-info/METADATA").decode()
    assert "Summary: edgerv's ROS 2 interfaces (edgerv_msgs)" in meta
    assert "Requires-Dist: ros-x~=1" in meta


def test_edgerv_types_build_without_packages_or_tools_exits_2(
    defs: Path, tmp_path: Path, no_tools: None
) -> None:
    empty = tmp_path / "nothing"
    empty.mkdir()
    proc = edgerv("types", "build", empty)
    assert proc.returncode == 2
    assert "no interface package" in proc.stderr
    proc = edgerv("types", "build", defs, "--no-pip", "--types-cache", tmp_path / "c")
    assert proc.returncode == 2
    assert "cannot build here: no cmake" in proc.stderr
    proc = edgerv("types", "build", defs / "my_robot_msgs", "--types-cache", "none")
    assert proc.returncode == 2 and "nowhere to build" in proc.stderr


def test_a_build_that_fails_is_reported_with_its_log_and_not_tried_again(
    defs: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A stand-in cmake that fails: the handler's message names the log, keeps it, and the
    next monitor on the same definitions is refused at once."""
    calls = tmp_path / "calls"
    fake = tmp_path / "bin"
    fake.mkdir()
    (fake / "cmake").write_text(
        f"#!/bin/sh\necho x >> {calls}\n"
        'case "$1" in --version) echo "cmake version 3.25.1";; '
        '*) echo "CMake Error at CMakeLists.txt:12: rosidl says no" ; exit 1;; esac\n'
    )
    (fake / "cmake").chmod(0o755)
    monkeypatch.setenv("PATH", f"{fake}:{ros_types.os.environ['PATH']}")
    with pytest.raises(TypesError) as info:
        ros_types.message_class("my_robot_msgs/msg/State")
    text = str(info.value)
    assert "building common_msgs from" in text and "rosidl says no" in text
    log = Path(re.findall(r"the whole log: (\S+)\)", text)[0])
    assert log.is_file() and "rosidl says no" in log.read_text()
    assert not [p for p in (tmp_path / "cache").iterdir() if p.is_dir()]  # no entry, no stage
    before = calls.read_text().count("x")
    with pytest.raises(TypesError, match="rosidl says no"):
        ros_types.message_class("my_robot_msgs/msg/Wheel")
    assert calls.read_text().count("x") == before  # not built again


@pytest.fixture(autouse=True)
def _fresh_state() -> Iterator[None]:
    """Each test starts with nothing built, loaded or failed in this process."""
    saved = (dict(ros_types._active), dict(ros_types._failed), ros_types._cache_given)
    ros_types._failed.clear()
    ros_types._identity = None
    yield
    ros_types._active.clear()
    ros_types._active.update(saved[0])
    ros_types._failed.clear()
    ros_types._failed.update(saved[1])
    ros_types._cache_given = saved[2]


FAKE_CMAKE = r'''#!{python}
"""A stand-in for cmake: configure notes the install prefix and the project's files,
--install writes a Python package with a class per .msg file (no compiler runs)."""
import json, pathlib, sys
args = sys.argv[1:]
with open({calls!r}, "a") as f:
    f.write(json.dumps(args) + "\n")
if args[0] == "--version":
    print("cmake version 3.25.1")
elif args[0] == "-S":
    src, build = pathlib.Path(args[1]), pathlib.Path(args[3])
    prefix = next(a.split("=", 1)[1] for a in args if a.startswith("-DCMAKE_INSTALL_PREFIX="))
    build.mkdir(parents=True)
    (build / "plan.json").write_text(json.dumps({{
        "prefix": prefix, "name": (src / "package.xml").read_text().split("<name>")[1]
        .split("<")[0], "msgs": [p.stem for p in (src / "msg").glob("*.msg")],
        "cmake": (src / "CMakeLists.txt").read_text()}}))
elif args[0] == "--install":
    plan = json.loads((pathlib.Path(args[1]) / "plan.json").read_text())
    site = pathlib.Path(plan["prefix"]) / "lib" / "python{version}" / "site-packages"
    (site / plan["name"] / "msg").mkdir(parents=True)
    (site / plan["name"] / "__init__.py").write_text("")
    (site / plan["name"] / "msg" / "__init__.py").write_text(
        "".join(f"class {{m}}:\n    built = True\n" for m in plan["msgs"]))
    share = pathlib.Path(plan["prefix"]) / "share" / plan["name"]
    share.mkdir(parents=True)
    (share / "CMakeLists.txt").write_text(plan["cmake"])
'''


@pytest.fixture
def fake_cmake(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """cmake is :data:`FAKE_CMAKE` (its calls, one JSON line each, in the file returned)."""
    calls = tmp_path / "cmake-calls"
    calls.touch()
    bin_dir = tmp_path / "fake-bin"
    bin_dir.mkdir()
    version = f"{sys.version_info[0]}.{sys.version_info[1]}"
    script = FAKE_CMAKE.format(python=sys.executable, calls=str(calls), version=version)
    (bin_dir / "cmake").write_text(script)
    (bin_dir / "cmake").chmod(0o755)
    monkeypatch.setenv("PATH", f"{bin_dir}{os.pathsep}{os.environ['PATH']}")
    return calls


MODULES = ("my_robot_msgs", "my_robot_msgs.msg", "common_msgs", "common_msgs.msg")


@pytest.fixture
def new_process(monkeypatch: pytest.MonkeyPatch) -> Iterator[Callable[[], None]]:
    """What starts a process afresh as far as the built types go (nothing loaded, nothing
    on sys.path); done again at the test's end."""
    monkeypatch.setattr(sys, "path", list(sys.path))
    path = list(sys.path)

    def fresh() -> None:
        ros_types._active.clear()
        sys.path[:] = path
        for name in MODULES:
            sys.modules.pop(name, None)

    fresh()
    yield fresh
    fresh()


def test_a_type_is_built_once_into_the_cache_and_loaded_from_it(
    defs: Path, tmp_path: Path, fake_cmake: Path, new_process: Callable[[], None]
) -> None:

    state = ros_types.message_class("my_robot_msgs/msg/State")
    assert state.__name__ == "State" and state.built
    cache = tmp_path / "cache"
    entries = sorted(p.name for p in cache.iterdir() if p.is_dir())
    steps = plan("my_robot_msgs", cache=cache)
    assert entries == [s.entry(cache).name for s in steps]  # common_msgs first, each its own
    meta = json.loads((cache / entries[1] / "build.json").read_text())
    assert meta["package"] == "my_robot_msgs" and meta["files"] == [
        "msg/State.msg",
        "msg/Wheel.msg",
    ]
    assert meta["customs"] == {"common_msgs": entries[0]}
    assert set(meta["externals"]) == {"geometry_msgs", "std_msgs"}
    # the build of my_robot_msgs is given common_msgs' prefix, and the project made for it
    calls = [json.loads(line) for line in fake_cmake.read_text().splitlines()]
    configures = [c for c in calls if c[0] == "-S"]
    assert len(configures) == 2
    prefixes = next(a for a in configures[1] if a.startswith("-DCMAKE_PREFIX_PATH=")).split(";")
    assert str(cache / entries[0] / "prefix") in prefixes[0]
    assert (
        "DEPENDENCIES common_msgs geometry_msgs std_msgs"
        in (
            cache / entries[1] / "prefix" / "share" / "my_robot_msgs" / "CMakeLists.txt"
        ).read_text()
    )
    # another process (nothing loaded): found in the cache, nothing built again
    new_process()
    before = len(calls)
    wheel = ros_types.message_class("my_robot_msgs/msg/Wheel")
    assert wheel.__name__ == "Wheel"
    assert len(fake_cmake.read_text().splitlines()) == before  # no cmake at all
    # a changed definition is another digest: built at its first use
    new_process()
    (defs / "my_robot_msgs" / "msg" / "State.msg").write_text(STATE + "bool docked\n")
    ros_types.message_class("my_robot_msgs/msg/State")
    assert len([p for p in cache.iterdir() if p.is_dir()]) == 3  # common_msgs is the same


def test_edgerv_types_build_pip_installs_ross_missing_build_packages_then_builds(
    defs: Path,
    tmp_path: Path,
    fake_cmake: Path,
    new_process: Callable[[], None],
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    real = ros_types.check_tools
    installed: list[list[str]] = []

    def check_tools() -> ros_types.Tools:
        if not installed:
            raise MissingTools(["ROS's build tools are not installed: pip install x"], ["x"])
        return real()

    def pip_install(requirements: list[str]) -> bool:
        installed.append(requirements)
        return True

    monkeypatch.setattr(ros_types, "check_tools", check_tools)
    monkeypatch.setattr(ros_types, "_pip_install", pip_install)
    proc = edgerv("types", "build", defs, "--types-cache", tmp_path / "c")
    assert proc.returncode == 0, proc.stderr
    assert installed == [["x"]]
    assert [line.split(":")[0] for line in proc.stdout.splitlines()] == [
        "common_msgs",
        "my_robot_msgs",
    ]
    assert all(": built in " in line for line in proc.stdout.splitlines())
    # with --no-pip: what is missing, exit 2
    installed.clear()
    proc = edgerv("types", "build", defs, "--types-cache", tmp_path / "d", "--no-pip")
    assert proc.returncode == 2 and "pip install x" in proc.stderr and not installed
