"""A newcomer's path through README.md, its commands run as written (issue #39): the quick
start (install, a first verdict on JSON Lines, the same run as a rosbag2 bag, `make tour`),
"Check a recorded run" (monitor.yaml as the README shows it), "Run the monitors live" (the
handler in one shell, `edgerv replay` in another) and "Your own robot" (a package of the
robot's own message types, built at its first use, checked and run live).

Each command is the ```sh block that follows ``<!-- recipe: NAME -->`` in README.md, run by
bash in a directory laid out as a clone (a link to each of the repository's top-level
entries, `.venv` included, so what the commands write stays there), with two changes a
shared machine needs: the ROS domain (``ROS_DOMAIN_ID=0``) is the test's own and the API's
port (8470) a free one; and discovery stays on this machine
(``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``). `make install` is the repository's own: it
must be done (as ``make test`` does first); the test reinstalls nothing. The message types
of the robot's package are built in a types cache of the test's own, as a newcomer's first
build (about 30 s on 2 cores).
"""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from kit.ros import free_port, ros_env, wait_for

pytest.importorskip("rclpy")

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
OUTPUTS = {"demo-output", "run", "run-db3", "run.jsonl", "monitor.yaml", "verdicts.jsonl"}
OUTPUTS |= {"my-robot-verdicts.jsonl"}


def recipe(name: str) -> str:
    """The ```sh block that follows ``<!-- recipe: NAME -->`` in README.md."""
    found = re.search(
        rf"<!-- recipe: {re.escape(name)} -->\s*```sh\n(.*?)```", README.read_text(), re.DOTALL
    )
    assert found, f"README.md has no '<!-- recipe: {name} -->' sh block"
    return found.group(1)


def commands(block: str) -> list[str]:
    """A block's commands: its lines joined at a trailing backslash, comments and blank
    lines left out (a command's own trailing comment stays, as bash reads it)."""
    joined = re.sub(r"\\\n\s*", " ", block)
    return [line for line in joined.splitlines() if line.strip() and not line.startswith("#")]


@pytest.fixture
def clone(tmp_path: Path) -> Path:
    """A directory that looks like a clone with `make install` done: a link to each
    top-level entry of the repository (the README's outputs left out)."""
    done = subprocess.run(["make", "-q", "install"], cwd=ROOT, capture_output=True)
    if done.returncode != 0:
        pytest.skip("`make install` is not up to date here (make test runs it first)")
    work = tmp_path / "edgerv"
    work.mkdir()
    for entry in ROOT.iterdir():
        if entry.name not in OUTPUTS and not entry.name.startswith(".git"):
            (work / entry.name).symlink_to(entry)
    return work


class Shell:
    """bash scripts run in the clone, with this test's domain, port and types cache."""

    def __init__(self, clone: Path, domain: int, cache: Path) -> None:
        self.clone, self.domain, self.port = clone, domain, free_port()
        base = {k: v for k, v in os.environ.items() if k not in ("VIRTUAL_ENV", "EDGERV_TOKEN")}
        venv_bin = str(ROOT / ".venv" / "bin")
        path = os.pathsep.join(p for p in base.get("PATH", "").split(os.pathsep) if p != venv_bin)
        self.env = ros_env(domain, PATH=path, EDGERV_TYPES_CACHE=str(cache))
        self.env.pop("EDGERV_MSG_PATH", None)  # the README's commands set it

    def script(self, block: str, *, activate: bool = False) -> str:
        text = block.replace("ROS_DOMAIN_ID=0", f"ROS_DOMAIN_ID={self.domain}")
        text = text.replace("127.0.0.1:8470", f"127.0.0.1:{self.port}")
        return (". .venv/bin/activate\n" if activate else "") + text

    def run_each(self, block: str, timeout: float = 600) -> list[tuple[str, int, str]]:
        """Each command of the block in one bash session: (command, exit code, output)."""
        cmds = commands(self.script(block))
        text = "".join(f"{c}\necho '@@rc {i}' $? >&2\n" for i, c in enumerate(cmds))
        done = subprocess.run(
            ["bash", "-c", text],
            cwd=self.clone,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )
        out = done.stdout + done.stderr
        codes = dict(re.findall(r"^@@rc (\d+) (\d+)$", done.stderr, re.MULTILINE))
        assert len(codes) == len(cmds), f"the block stopped early:\n{out}"
        return [(c, int(codes[str(i)]), out) for i, c in enumerate(cmds)]

    def run(
        self, block: str, *, activate: bool = True, timeout: float = 120
    ) -> subprocess.CompletedProcess[str]:
        return subprocess.run(
            ["bash", "-c", self.script(block, activate=activate)],
            cwd=self.clone,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=timeout,
        )

    def start(self, block: str, log: Path) -> subprocess.Popen[bytes]:
        """A block that ends in a long-running command (the handler), in a session of its
        own, with its output in ``log``."""
        with log.open("w") as out:
            return subprocess.Popen(
                ["bash", "-c", self.script(block, activate=True)],
                cwd=self.clone,
                env=self.env,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )

    def edgerv_json(self, *args: str) -> dict[str, Any]:
        done = subprocess.run(
            [sys.executable, "-m", "edgerv", "check", *args, "--json"],
            cwd=self.clone,
            env=self.env,
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert done.returncode in (0, 1), done.stderr
        return json.loads(done.stdout)


def stop(proc: subprocess.Popen[bytes], log: Path) -> str:
    """SIGTERM to the handler's session (its bash and the handler), its output."""
    if proc.poll() is None:
        os.killpg(proc.pid, signal.SIGTERM)
    try:
        proc.wait(timeout=30)
    except subprocess.TimeoutExpired:
        os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
    return log.read_text()


def verdicts(path: Path) -> list[tuple[str, str, int, int]]:
    rows = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return sorted((r["monitor"], r["verdict"], r["step"], r["stamp"]) for r in rows)


def checked(report: dict[str, Any]) -> list[tuple[str, str, int, int]]:
    return sorted(
        (m["name"], v["verdict"], v["step"], v["stamp"])
        for m in report["monitors"]
        for v in m["verdicts"]
    )


def test_quick_start_check_and_live(clone: Path, domain: int, tmp_path: Path) -> None:
    sh = Shell(clone, domain, tmp_path / "types")

    # Quick start, command by command: install (done), activate, a first verdict on JSON
    # Lines, the bag of the same run and its verdict, make tour.
    ran = sh.run_each(recipe("quick-start"))
    codes = [(c.split("#")[0].strip(), rc) for c, rc, _ in ran]
    expected = {"edgerv check": 1, "python examples/trace_to_bag.py": 0, "make": 0, ".": 0}
    for command, rc in codes:
        want = next(v for k, v in expected.items() if command.startswith(k))
        assert rc == want, f"{command!r} exited {rc}, not {want}:\n{ran[0][2]}"
    assert (clone / "run" / "run.mcap").is_file() and (clone / "run" / "metadata.yaml").is_file()
    on_trace = sh.edgerv_json("examples/speed-limit.yaml", "examples/speed-limit.jsonl")
    assert checked(sh.edgerv_json("examples/speed-limit.yaml", "run")) == checked(on_trace)
    assert any(v[1] == "violated" for v in checked(on_trace))

    # "Check a recorded run": monitor.yaml as the README shows it, run.jsonl the example's
    # run (as the README says), and the sqlite3 bag its text names.
    text = README.read_text()
    monitor = re.search(r"```yaml\n(# monitor\.yaml.*?)```", text, re.DOTALL)
    assert monitor, "README.md's monitor.yaml block is gone"
    (clone / "monitor.yaml").write_text(monitor.group(1))
    copy = re.search(r"`(cp examples/speed-limit\.jsonl run\.jsonl)`", text)
    db3 = re.search(
        r"`(python examples/trace_to_bag\.py monitor\.yaml run\.jsonl \S+ --storage sqlite3)`", text
    )
    assert copy and db3, "README.md's 'no recording at hand' commands are gone"
    for command in (copy.group(1), db3.group(1)):
        done = sh.run(command)
        assert done.returncode == 0, done.stdout + done.stderr
    offline = checked(sh.edgerv_json("monitor.yaml", "run.jsonl"))
    assert offline and checked(sh.edgerv_json("monitor.yaml", db3.group(1).split()[4])) == offline

    # "Run the monitors live": the handler in one shell, the replay in another.
    log = tmp_path / "handler.log"
    handler = sh.start(recipe("live-handler"), log)
    try:
        assert wait_for(lambda: " ready: " in log.read_text(), timeout=60), log.read_text()
        replay = sh.run(recipe("live-replay"), activate=False)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        want = [(m, v, step) for m, v, step, _ in offline]
        got = lambda: [(m, v, s) for m, v, s, _ in verdicts(clone / "verdicts.jsonl")]  # noqa: E731
        assert wait_for(
            lambda: (clone / "verdicts.jsonl").exists() and got() == want, timeout=20
        ), got()
    finally:
        out = stop(handler, log)
    assert "monitor speed-limit violated at step 3" in out, out
    assert "handler edge-1 stopped" in out, out


def test_own_robot_types_live(clone: Path, domain: int, tmp_path: Path) -> None:
    """ "Your own robot": a package of its own types, checked, then built at its first use
    by the handler, published by `edgerv replay`: the live verdicts are the check's, at
    the same stamps (the messages' header stamps)."""
    sh = Shell(clone, domain, tmp_path / "types")
    done = sh.run(recipe("own-types-check"))
    assert done.returncode == 1, done.stdout + done.stderr
    sh.env["EDGERV_MSG_PATH"] = str(clone / "examples" / "robot_ws" / "src")
    offline = checked(sh.edgerv_json("examples/my-robot.yaml", "examples/my-robot.jsonl"))
    del sh.env["EDGERV_MSG_PATH"]
    assert {m for m, *_ in offline} == {"battery-in-auto", "no-slip"}

    log = tmp_path / "handler.log"
    handler = sh.start(recipe("own-types-handler"), log)
    try:
        ready = wait_for(lambda: " ready: " in log.read_text() or handler.poll() is not None, 180)
        assert ready and handler.poll() is None, log.read_text()
        assert "built my_robot_msgs in" in log.read_text()
        replay = sh.run(recipe("own-types-replay"), activate=False)
        assert replay.returncode == 0, replay.stdout + replay.stderr
        path = clone / "my-robot-verdicts.jsonl"
        assert wait_for(lambda: path.exists() and verdicts(path) == offline, 20), (
            verdicts(path) if path.exists() else log.read_text()
        )
    finally:
        out = stop(handler, log)
    assert "monitor battery-in-auto violated at step 6" in out, out
    assert "monitor no-slip violated at step 7" in out, out
