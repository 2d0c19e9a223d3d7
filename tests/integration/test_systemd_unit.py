"""packaging/systemd/edgerv-handler.service, the handler from a pip install under systemd.

Three levels, each real as far as the machine allows:

1. ``systemd-analyze verify`` and ``security --offline`` on the unit as written;
2. its ``ExecStart=`` run as systemd runs it (no systemd as PID 1 needed): the unit
   parsed, its ``Environment=`` then ``EnvironmentFile=`` (packaging/handler.env), its
   credentials in a ``$CREDENTIALS_DIRECTORY``, its specifiers and ``$VAR``/``${VAR}``
   expanded as systemd does, in a clean environment; against a real rclpy publisher,
   the verdicts equal to ``edgerv check``, SIGTERM (its ``KillSignal=``) ending it with
   exit 0 within ``TimeoutStopSec=``;
3. where Docker runs: packaging/README.md's install recipe as written, under systemd 252
   as PID 1 in a Debian 12 container made from the handler's image (whose /opt/edgerv is
   the venv the unit runs), the service's user, hardening, credentials, restart and stop
   checked for real.

Level 2 runs the handler as the test's user, not the unit's ``User=``: this machine's
venv lives under /root, which no other user may enter. Level 3 runs it as ``edgerv``.
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from kit import dockerimage
from kit.odom_run import MONITORS
from kit.pki import shared_pki
from kit.robotrun import ROBOT, https, log_verdicts, messages_taken, publish_run
from kit.ros import free_port, offline_verdicts, robot_env, wait_for

pytestmark = pytest.mark.integration

ROOT = Path(__file__).resolve().parents[2]
UNIT = ROOT / "packaging" / "systemd" / "edgerv-handler.service"
ENV_FILE = ROOT / "packaging" / "handler.env"
README = ROOT / "packaging" / "README.md"


def unit_settings(path: Path) -> dict[str, list[str]]:
    """The unit's [Service] settings, each key's values in order (continued lines joined,
    comments dropped), as systemd reads them."""
    settings: dict[str, list[str]] = {}
    section, pending = "", ""
    for raw in path.read_text().splitlines():
        line = pending + raw.strip() if pending else raw.strip()
        pending = ""
        if not line or line[0] in "#;":
            continue
        if line.endswith("\\"):
            pending = line[:-1] + " "
            continue
        if line.startswith("["):
            section = line.strip("[]")
            continue
        key, _, value = line.partition("=")
        if section == "Service":
            settings.setdefault(key.strip(), []).append(value.strip())
    return settings


def env_file(path: Path) -> dict[str, str]:
    """An EnvironmentFile= as systemd reads it (the file here has no quotes)."""
    out = {}
    for line in path.read_text().splitlines():
        if line.strip() and not line.lstrip().startswith(("#", ";")):
            key, _, value = line.partition("=")
            out[key.strip()] = value.strip()
    return out


def expand_command(command: str, env: dict[str, str]) -> list[str]:
    """ExecStart='s words, as systemd makes them: ``${VAR}`` is the variable's value in one
    word, a word that is only ``$VAR`` becomes the value's words (none when empty)."""
    words: list[str] = []
    for word in shlex.split(command):
        whole = re.fullmatch(r"\$([A-Za-z_]\w*)", word)
        if whole:
            words += env.get(whole.group(1), "").split()
        else:
            words.append(re.sub(r"\$\{([A-Za-z_]\w*)\}", lambda m: env.get(m.group(1), ""), word))
    return words


class Emulated:
    """The unit's ExecStart= started as systemd would start it, its directories (/etc/edgerv,
    %S, %L, %C) under ``root`` and /opt/edgerv/bin this venv's."""

    def __init__(self, root: Path, handler_env: Path, extra_env: dict[str, str] | None = None):
        s = unit_settings(UNIT)
        dirs = {"%S": root / "var/lib", "%L": root / "var/log", "%C": root / "var/cache"}
        specifiers = {**{k: str(v) for k, v in dirs.items()}, "%H": socket.gethostname()}
        etc = root / "etc" / "edgerv"

        def local(text: str) -> str:
            for spec, value in specifiers.items():
                text = text.replace(spec, value)
            text = text.replace("/etc/edgerv", str(etc))
            return text.replace("/opt/edgerv/bin/", str(Path(sys.executable).parent) + "/")

        for key, base in (("StateDirectory", "%S"), ("LogsDirectory", "%L"),
                          ("CacheDirectory", "%C")):  # fmt: skip
            for name in s.get(key, []):
                (dirs[base] / name).mkdir(parents=True, exist_ok=True)
        creds = root / "run" / "credentials" / "edgerv-handler.service"
        creds.mkdir(parents=True)
        for spec in s["LoadCredential"]:
            ident, _, source = spec.partition(":")
            shutil.copy(local(source), creds / ident)
            (creds / ident).chmod(0o400)
        # systemd's own environment for a service: PATH, and what User= sets
        self.env = {"PATH": "/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin",
                    "LANG": "C.UTF-8", "CREDENTIALS_DIRECTORY": str(creds)}  # fmt: skip
        for assignment in s.get("Environment", []):
            for word in shlex.split(assignment):
                key, _, value = word.partition("=")
                self.env[key] = local(value)
        [file] = s["EnvironmentFile"]
        assert local(file.lstrip("-")) == str(etc / "handler.env")
        self.env.update(env_file(handler_env))
        self.env.update(extra_env or {})
        [command] = s["ExecStart"]
        self.argv = expand_command(local(command), self.env)
        self.stop_timeout = float(s["TimeoutStopSec"][0])
        self.kill_signal = getattr(signal, s["KillSignal"][0])
        self.state = dirs["%S"] / "edgerv"
        self.stderr_path = root / "stderr.log"
        self._stderr = self.stderr_path.open("w")
        self.proc = subprocess.Popen(
            self.argv, env=self.env, stdin=subprocess.DEVNULL, stdout=self._stderr,
            stderr=subprocess.STDOUT, cwd="/",
        )  # fmt: skip

    @property
    def output(self) -> str:
        return self.stderr_path.read_text()

    def stop(self) -> tuple[int, float]:
        began = time.monotonic()
        if self.proc.poll() is None:
            self.proc.send_signal(self.kill_signal)
        try:
            code = self.proc.wait(timeout=self.stop_timeout)
        finally:
            if self.proc.poll() is None:  # as systemd would: SIGKILL after TimeoutStopSec
                self.proc.kill()
                self.proc.wait()
            self._stderr.close()
        return code, time.monotonic() - began


def install_files(tmp: Path, domain: int, listen: str, discovery: str) -> Path:
    """What packaging/README.md's recipe starts from: handler.env (edited), the
    certificate and key, the monitors; laid out in ``tmp`` as the recipe installs them
    (/etc/edgerv) for the emulated start, and in ``tmp/work`` for the recipe itself."""
    text = ENV_FILE.read_text()
    for line in ("ROS_DOMAIN_ID=0", "ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET",
                 "FASTDDS_BUILTIN_TRANSPORTS=UDPv4", "#EDGERV_LISTEN=0.0.0.0:8470"):  # fmt: skip
        assert re.search(rf"^{re.escape(line)}$", text, re.M), line
    text = text.replace("ROS_DOMAIN_ID=0\n", f"ROS_DOMAIN_ID={domain}\n")
    text = text.replace("=SUBNET\n", f"={discovery}\n")
    text = text.replace("#EDGERV_LISTEN=0.0.0.0:8470\n", f"EDGERV_LISTEN={listen}\n")
    certs = shared_pki()
    work = tmp / "work"
    (work / "monitors").mkdir(parents=True)
    (work / "handler.env").write_text(text)
    shutil.copy(certs.crt, work / "handler.crt")
    shutil.copy(certs.key, work / "handler.key")
    (work / "monitors" / "robot.yaml").write_text(MONITORS)
    shutil.copy(UNIT, work / "edgerv-handler.service")
    etc = tmp / "etc" / "edgerv"
    (etc / "monitors").mkdir(parents=True)
    shutil.copy(work / "handler.env", etc / "handler.env")
    (etc / "token").write_text("unit-test-token\n")
    shutil.copy(certs.crt, etc / "tls.crt")
    shutil.copy(certs.key, etc / "tls.key")
    shutil.copy(work / "monitors" / "robot.yaml", etc / "monitors" / "robot.yaml")
    return work


# -- 1. systemd-analyze ------------------------------------------------------------------------


def test_systemd_analyze_verifies_the_unit_and_rates_its_exposure_low(tmp_path: Path) -> None:
    if shutil.which("systemd-analyze") is None:
        pytest.skip("systemd-analyze is not installed (apt-get install systemd)")
    # as written, but for the venv's path: /opt/edgerv does not exist on this machine
    unit = tmp_path / UNIT.name
    unit.write_text(
        UNIT.read_text().replace("/opt/edgerv/bin/", str(Path(sys.executable).parent) + "/")
    )
    verify = subprocess.run(
        ["systemd-analyze", "verify", str(unit)], capture_output=True, text=True, timeout=60
    )
    assert verify.returncode == 0, verify.stderr
    assert verify.stderr.strip() == "", verify.stderr
    security = subprocess.run(
        ["systemd-analyze", "security", "--offline=yes", "--no-pager", str(unit)],
        capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    found = re.search(r"Overall exposure level for \S+: ([\d.]+) (\w+)", security.stdout)
    assert found, security.stdout + security.stderr
    assert float(found.group(1)) <= 2.5 and found.group(2) == "OK", found.group(0)


def test_the_unit_keeps_secrets_off_the_command_line_and_stops_after_its_drain() -> None:
    s = unit_settings(UNIT)
    [command] = s["ExecStart"]
    assert "--token-file ${CREDENTIALS_DIRECTORY}/token" in command
    assert "--tls-key ${CREDENTIALS_DIRECTORY}/tls.key" in command
    assert "EDGERV_TOKEN" not in UNIT.read_text()
    assert s["KillSignal"] == ["SIGTERM"] and s["Restart"] == ["on-failure"]
    defaults = dict(w.split("=", 1) for a in s["Environment"] for w in shlex.split(a))
    drain = float(env_file(ENV_FILE).get("EDGERV_DRAIN", defaults["EDGERV_DRAIN"]))
    assert float(s["TimeoutStopSec"][0]) >= drain + 15
    assert s["User"] == ["edgerv"] and s["NoNewPrivileges"] == ["yes"]


# -- 2. ExecStart as systemd runs it -----------------------------------------------------------


def test_the_units_command_runs_the_handler_that_gives_the_verdicts_of_edgerv_check(
    tmp_path: Path, domain: int
) -> None:
    port = free_port()
    install_files(tmp_path, domain, f"127.0.0.1:{port}", "LOCALHOST")
    handler = Emulated(tmp_path, tmp_path / "etc" / "edgerv" / "handler.env")
    certs = shared_pki()
    try:
        wait_for(lambda: " ready: " in handler.output or handler.proc.poll() is not None, 60)
        assert " ready: " in handler.output, handler.output
        assert "unit-test-token" not in " ".join(handler.argv)
        trace = tmp_path / "run.jsonl"
        published = publish_run(trace, robot_env(domain, "LOCALHOST"))
        taken = wait_for(
            lambda: (t := messages_taken(port, certs.ca)) == published and t, timeout=30
        )
        assert taken == published, (taken, published, handler.output)
        assert https(port, "/v1/monitors", "unit-test-token", certs.ca)[0] == 200
        assert https(port, "/v1/monitors", None, certs.ca)[0] == 401
    finally:
        code, took = handler.stop()
    assert code == 0, handler.output
    assert took < handler.stop_timeout
    log = (handler.state / "verdicts.jsonl").read_text()
    offline = offline_verdicts(tmp_path / "work" / "monitors" / "robot.yaml", trace)
    assert len(offline) > 20
    assert log_verdicts(log) == offline
    assert {json.loads(line)["handler"] for line in log.splitlines()} == {socket.gethostname()}


def test_a_setting_the_handler_refuses_exits_2_which_the_unit_does_not_restart(
    tmp_path: Path, domain: int
) -> None:
    install_files(tmp_path, domain, "127.0.0.1:8470", "LOCALHOST")
    handler = Emulated(
        tmp_path, tmp_path / "etc" / "edgerv" / "handler.env", {"EDGERV_LISTEN": "nowhere"}
    )
    code = handler.proc.wait(timeout=60)
    handler.stop()
    assert code == 2, handler.output
    assert "2" in unit_settings(UNIT)["RestartPreventExitStatus"][0].split()


# -- 3. under systemd as PID 1 -----------------------------------------------------------------

SYSTEMD_IMAGE = """\
FROM {base}
USER root
RUN apt-get update -q \\
 && DEBIAN_FRONTEND=noninteractive apt-get install -y -q --no-install-recommends \\
        systemd systemd-sysv dbus \\
 && rm -rf /var/lib/apt/lists/*
ENTRYPOINT ["/lib/systemd/systemd"]
CMD []
"""


# Can systemd hand a service's user a credential here (no: a container without ACLs)?
CREDENTIALS_PROBE = """\
id -u edgerv-probe >/dev/null 2>&1 || useradd --system --no-create-home edgerv-probe
systemd-run --quiet --wait --pipe -p User=edgerv-probe -p LoadCredential=probe:/etc/hostname \\
    sh -c 'test -r "$CREDENTIALS_DIRECTORY/probe" && echo readable || echo unreadable'
"""


class Machine:
    """A container with systemd as its PID 1, on the host's network."""

    def __init__(self, image: str, name: str) -> None:
        self.name = name
        dockerimage.docker("rm", "--force", name, check=False)
        dockerimage.docker(
            "run", "--detach", "--name", name, "--network", "host",
            "--cap-add", "SYS_ADMIN", "--security-opt", "seccomp=unconfined",
            "--tmpfs", "/run", "--tmpfs", "/run/lock",
            "--volume", "/sys/fs/cgroup:/sys/fs/cgroup:rw", image,
        )  # fmt: skip

    def sh(self, script: str, check: bool = True, timeout: float = 120) -> str:
        done = dockerimage.docker(
            "exec", self.name, "bash", "-euc", script, check=False, timeout=timeout
        )
        if check and done.returncode != 0:
            raise AssertionError(f"{script}\nexit {done.returncode}:\n{done.stdout}{done.stderr}")
        return done.stdout

    def show(self, *props: str) -> dict[str, str]:
        out = self.sh(f"systemctl show edgerv-handler -p {','.join(props)}")
        return dict(line.split("=", 1) for line in out.splitlines() if "=" in line)

    def journal(self) -> str:
        return self.sh("journalctl -u edgerv-handler --no-pager -o cat", check=False)


@pytest.fixture(scope="module")
def systemd_image() -> str:
    reason = dockerimage.why_no_docker()
    if reason is not None:
        pytest.skip(f"Docker cannot run here: {reason}")
    base = dockerimage.handler_image()
    return dockerimage.derived_image(
        "edgerv-test/handler-systemd:dev", SYSTEMD_IMAGE.format(base=base)
    )


def test_the_documented_install_runs_under_systemd_as_pid_1(
    systemd_image: str, tmp_path: Path, domain: int
) -> None:
    port = free_port()
    work = install_files(tmp_path, domain, f"0.0.0.0:{port}", "SUBNET")
    recipe = re.search(
        r"<!-- recipe: systemd-install -->\s*```sh\n(.*?)```", README.read_text(), re.DOTALL
    )
    assert recipe, "packaging/README.md has no systemd-install recipe"
    machine = Machine(systemd_image, f"edgerv-systemd-{os.getpid()}")
    certs = shared_pki()
    try:
        wait_for(
            lambda: (
                machine.sh("systemctl is-system-running", check=False).strip()
                in ("running", "degraded")
            ),
            timeout=60,
        )
        dockerimage.docker("cp", str(work), f"{machine.name}:/root/work")
        credentials = machine.sh(CREDENTIALS_PROBE, check=False).strip() == "readable"
        if not credentials:
            # this systemd cannot hand a service's user its credentials here (no ACLs on
            # the container's file systems, as under gVisor): the documented drop-in
            print(
                "\nno credentials for a service's user here: packaging/systemd/no-credentials.conf"
            )
            drop_in = (ROOT / "packaging" / "systemd" / "no-credentials.conf").read_text()
            setup = re.findall(r"^#   (ch\w+ .*)$", drop_in, re.M)
            assert len(setup) == 2, drop_in
            recipe_text = recipe.group(1).replace(
                "systemctl daemon-reload",
                "mkdir -p /etc/systemd/system/edgerv-handler.service.d\n"
                "cp no-credentials.conf /etc/systemd/system/edgerv-handler.service.d/\n"
                + "\n".join(setup)
                + "\nsystemctl daemon-reload",
            )
            dockerimage.docker(
                "cp", str(ROOT / "packaging" / "systemd" / "no-credentials.conf"),
                f"{machine.name}:/root/work/no-credentials.conf",
            )  # fmt: skip
        else:
            recipe_text = recipe.group(1)
        machine.sh(f"cd /root/work && {recipe_text}")
        wait_for(lambda: " ready: " in machine.journal(), timeout=60)
        assert " ready: " in machine.journal(), machine.journal()

        # as the user edgerv, hardened, the token a credential
        props = machine.show("MainPID", "User", "ActiveState")
        assert props["ActiveState"] == "active" and props["User"] == "edgerv"
        pid = props["MainPID"]
        status = machine.sh(f"cat /proc/{pid}/status")
        fields = dict(re.findall(r"^(\w+):\s+(.*)$", status, re.M))
        assert fields["Uid"].split()[0] == machine.sh("id -u edgerv").strip()
        assert fields["NoNewPrivs"] == "1" and fields["Seccomp"] == "2", status
        assert int(fields["CapEff"], 16) == 0 and int(fields["CapBnd"], 16) == 0, status
        token = machine.sh("cat /etc/edgerv/token").strip()
        process = machine.sh(
            f"tr '\\0' ' ' < /proc/{pid}/cmdline; tr '\\0' ' ' < /proc/{pid}/environ"
        )
        assert token not in process
        if credentials:
            assert "--token-file /run/credentials/edgerv-handler.service/token" in process
        assert "/dev/shm" in machine.sh(f"cut -d' ' -f5 /proc/{pid}/mountinfo")

        # a crash: restarted (RestartSec=5)
        machine.sh(f"kill -KILL {pid}")
        wait_for(lambda: machine.show("NRestarts")["NRestarts"] == "1", timeout=30)
        wait_for(lambda: machine.journal().count(" ready: ") == 2, timeout=60)
        assert machine.journal().count(" ready: ") == 2, machine.journal()

        # the robot's run, on the host
        trace = tmp_path / "run.jsonl"
        published = publish_run(trace, robot_env(domain, "SUBNET"))
        taken = wait_for(
            lambda: (t := messages_taken(port, certs.ca)) == published and t, timeout=30
        )
        assert taken == published, (taken, published, machine.journal())
        assert https(port, "/v1/monitors", token, certs.ca)[0] == 200

        # systemctl stop: SIGTERM, exit 0, well within TimeoutStopSec
        began = time.monotonic()
        machine.sh("systemctl stop edgerv-handler")
        took = time.monotonic() - began
        props = machine.show("Result", "ExecMainStatus", "ExecMainCode", "TimeoutStopUSec")
        assert props["Result"] == "success" and props["ExecMainStatus"] == "0", props
        assert took < 10, took
        log = machine.sh("cat /var/lib/edgerv/verdicts.jsonl")
        owner = machine.sh("stat -c %U /var/lib/edgerv/verdicts.jsonl").strip()
        journal = machine.journal()

        # shared memory through the hardening (PrivateDevices= keeps /dev/shm): a node of
        # the service's user on the same machine, both discovering on LOCALHOST only, where
        # Fast DDS delivers between the machine's processes through shared memory alone
        machine.sh(
            "sed -i -e 's/^ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET$/&/;s/=SUBNET$/=LOCALHOST/'"
            " -e 's/^FASTDDS_BUILTIN_TRANSPORTS=UDPv4$/FASTDDS_BUILTIN_TRANSPORTS=DEFAULT/'"
            " /etc/edgerv/handler.env && systemctl start edgerv-handler"
        )
        wait_for(lambda: machine.journal().count(" ready: ") == 3, timeout=60)
        (tmp_path / "robot.py").write_text(ROBOT)
        dockerimage.docker("cp", str(tmp_path / "robot.py"), f"{machine.name}:/tmp/robot.py")
        local = machine.sh(
            f"cd /tmp && runuser -u edgerv -- env HOME=/tmp ROS_LOG_DIR=/tmp "
            f"ROS_DOMAIN_ID={domain} ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST "
            "/opt/edgerv/bin/python /tmp/robot.py /tmp/shm-run.jsonl 100 5"
        )
        shm_published = json.loads(local.strip().splitlines()[-1])
        shm_taken = wait_for(
            lambda: (t := messages_taken(port, certs.ca)) == shm_published and t, timeout=30
        )
        assert shm_taken == shm_published, (shm_taken, shm_published, machine.journal())
        machine.sh("systemctl stop edgerv-handler")
    finally:
        dockerimage.docker("rm", "--force", machine.name, check=False)
    assert owner == "edgerv"
    offline = offline_verdicts(work / "monitors" / "robot.yaml", trace)
    assert len(offline) > 20
    assert log_verdicts(log) == offline, journal
