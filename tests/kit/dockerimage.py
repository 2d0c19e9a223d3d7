"""Docker for the integration tests that run the handler's image (test_docker_run.py,
test_systemd_unit.py): a Docker daemon, started here when none runs (as tests/cluster
does: host networking only, no bridge, no iptables), and ``edgerv/handler:dev`` built
from this working tree as images/README.md says, on the Debian base tests/cluster makes
with debootstrap (no container registry is reachable there), reused when nothing changed.

Building: the locked wheels are downloaded once per lock (pip's cache), edgerv's wheel is
built with a fixed SOURCE_DATE_EPOCH (the same sources make the same bytes), and
``docker build`` then reuses every layer whose input did not change: a rebuild costs
about 10 s when nothing changed, a minute or two when edgerv's sources did, several
minutes cold (images/README.md, "docker run", gives the times measured).
"""

from __future__ import annotations

import atexit
import hashlib
import os
import re
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "images" / "README.md"
sys.path.insert(0, str(ROOT / "tests" / "cluster"))
import cluster  # noqa: E402  (tests/cluster/cluster.py: its base image and names)

HANDLER_IMAGE = cluster.HANDLER_IMAGE  # edgerv/handler:dev, as images/README.md builds it

_daemon: list[subprocess.Popen[bytes]] = []  # the dockerd started here, if any
_built: list[str] = []  # the handler's image, once built in this test process


def log(msg: str) -> None:
    print(f"docker: {msg}", file=sys.stderr, flush=True)


def docker(
    *args: str, check: bool = True, timeout: float = 120
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["docker", *args], check=check, text=True, capture_output=True, timeout=timeout
    )


def _answers() -> bool:
    try:
        return docker("info", check=False, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def why_no_docker() -> str | None:
    """None when a Docker daemon answers (started here if needed); else why Docker cannot
    run on this machine at all, for a skip. A daemon that should start but does not is a
    failure, not a skip."""
    if shutil.which("docker") is None:
        return "no docker command (apt-get install docker.io)"
    if _answers():
        return None
    if shutil.which("dockerd") is None:
        return "no Docker daemon runs and dockerd is not installed (apt-get install docker.io)"
    if os.geteuid() != 0:
        return "no Docker daemon runs, and starting one needs root"
    log("starting dockerd (host networking only: no bridge, no iptables), stopped at exit")
    out = open(Path(os.environ.get("TMPDIR", "/tmp")) / "edgerv-test-dockerd.log", "wb")  # noqa: SIM115
    # close_fds (Popen's default): a lock the caller holds (flock) stays with the caller
    proc = subprocess.Popen(
        ["dockerd", "--bridge=none", "--iptables=false", "--ip-masq=false"],
        stdout=out,
        stderr=subprocess.STDOUT,
        stdin=subprocess.DEVNULL,
        start_new_session=True,
    )
    _daemon.append(proc)
    atexit.register(_stop_daemon)
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"dockerd exited {proc.returncode}: see {out.name}")
        if _answers():
            return None
        time.sleep(0.5)
    raise TimeoutError(f"dockerd did not answer within 60 s: see {out.name}")


def _stop_daemon() -> None:
    for proc in _daemon:
        proc.terminate()
        try:
            proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def handler_image() -> str:
    """edgerv/handler:dev from this working tree (images/README.md's build, FROM the
    cluster's debootstrap base); a no-op for docker when nothing changed; once a test
    process."""
    if _built:
        return _built[0]
    started = time.monotonic()
    cluster.base_image()  # edgerv/base:bookworm (debootstrap + docker import), once
    context = cluster.CACHE / "image-context"  # shared with tests/cluster: one download
    wheels = context / "build" / "wheels"
    wheels.mkdir(parents=True, exist_ok=True)
    lock = ROOT / "images" / "handler" / "requirements.lock"
    (context / "handler").mkdir(exist_ok=True)
    shutil.copyfile(lock, context / "handler" / "requirements.lock")
    stamp = context / "build" / ".handler-lock.sha256"
    digest = hashlib.sha256(lock.read_bytes()).hexdigest()
    if not stamp.exists() or stamp.read_text() != digest:
        log("downloading the locked wheels (pip's cache makes this quick after the first)")
        subprocess.run(
            [sys.executable, "-m", "pip", "download", "--quiet", "--require-hashes",
             "--no-deps", "--dest", str(wheels), "-r", str(lock)],
            check=True,
        )  # fmt: skip
        stamp.write_text(digest)
    for old in [*wheels.glob("edgerv-*.whl"), *wheels.glob("edgerv_msgs-*.whl")]:
        old.unlink()
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--quiet", "--no-deps", "--wheel-dir",
         str(wheels), str(ROOT)],
        check=True, capture_output=True,
        env={**os.environ, "SOURCE_DATE_EPOCH": "315532800"},  # the same sources, the same bytes
    )  # fmt: skip
    built = sorted((ROOT / "images" / "build" / "wheels").glob("edgerv_msgs-*.whl"))
    if len(built) != 1:
        raise RuntimeError(
            f"{len(built)} edgerv_msgs wheels in images/build/wheels: `make install` "
            "(interfaces/build.sh) leaves the one the handler's image needs there"
        )
    shutil.copy(built[0], wheels)
    cluster.prune_stale_images()
    build = subprocess.run(
        ["docker", "build", "--quiet", "--network", "host", "--build-arg",
         f"BASE={cluster.BASE_IMAGE}", "-t", HANDLER_IMAGE, "-f",
         str(ROOT / "images" / "handler" / "Dockerfile"), str(context)],
        text=True, capture_output=True,
    )  # fmt: skip
    if build.returncode != 0:
        raise RuntimeError(f"docker build {HANDLER_IMAGE} failed:\n{build.stderr[-4000:]}")
    log(f"{HANDLER_IMAGE} up to date in {time.monotonic() - started:.0f} s")
    _built.append(HANDLER_IMAGE)
    return HANDLER_IMAGE


def derived_image(tag: str, dockerfile: str) -> str:
    """An image of the tests' own, FROM the handler's (e.g. with systemd), rebuilt when the
    handler's image or this Dockerfile changes (docker's cache)."""
    context = cluster.CACHE / "test-images" / re.sub(r"[^a-z0-9]+", "-", tag)
    context.mkdir(parents=True, exist_ok=True)
    (context / "Dockerfile").write_text(dockerfile)
    build = subprocess.run(
        ["docker", "build", "--quiet", "--network", "host", "-t", tag, str(context)],
        text=True, capture_output=True,
    )  # fmt: skip
    if build.returncode != 0:
        raise RuntimeError(f"docker build {tag} failed:\n{build.stderr[-4000:]}")
    return tag


# -- the recipes of images/README.md -----------------------------------------------------------


def readme_recipe(name: str, lang: str = "sh") -> str:
    """The ```sh block (or ```LANG: ``dockerfile``) that follows ``<!-- recipe: NAME -->``
    in images/README.md: the tests run the documented commands (and build the documented
    Dockerfiles) themselves, not a copy of them."""
    text = README.read_text()
    found = re.search(
        rf"<!-- recipe: {re.escape(name)} -->\s*```{re.escape(lang)}\n(.*?)```",
        text,
        flags=re.DOTALL,
    )
    if found is None:
        raise AssertionError(f"images/README.md has no '<!-- recipe: {name} -->' {lang} block")
    return found.group(1)


def with_values(recipe: str, values: dict[str, str]) -> str:
    """The recipe with its first line of ``NAME=value`` assignments (the values a reader
    sets for their machine) set to ``values``: the same names, no more, no fewer."""
    lines = recipe.splitlines()
    for i, line in enumerate(lines):
        words = line.split("#", 1)[0].split()
        if words and all(re.fullmatch(r"[A-Z_]+=\S*", w) for w in words):
            names = [w.split("=", 1)[0] for w in words]
            if sorted(names) != sorted(values):
                raise AssertionError(f"the recipe sets {names}, the test {sorted(values)}")
            lines[i] = " ".join(f"{k}={shlex.quote(v)}" for k, v in values.items())
            return "\n".join(lines) + "\n"
    raise AssertionError(f"no line of NAME=value assignments in the recipe:\n{recipe}")


def readme_run(etc: Path, data: Path, image: str, name: str, listen: str) -> str:
    """images/README.md's ``docker-run`` block with these values (ETC and DATA as
    :func:`readme_setup` gives them, the container's NAME, its API's LISTEN address), after
    a container of that name left by an earlier run is removed."""
    docker("rm", "--force", name, check=False)
    values = {"ETC": str(etc), "DATA": str(data), "IMAGE": image, "NAME": name, "LISTEN": listen}
    return with_values(readme_recipe("docker-run"), values)


def readme_setup(tmp: Path, domain: int, monitors: str) -> tuple[Path, Path, Path]:
    """What a reader of images/README.md has at hand, then its ``docker-setup`` block run:
    a work directory with handler.env (packaging/handler.env, the test's domain set), the
    shared certificate and its key, and ``monitors`` as monitors/robot.yaml. Returns the
    work directory and the block's ETC and DATA (under ``tmp``)."""
    from kit.pki import shared_pki

    certs = shared_pki()
    work = tmp / "work"
    (work / "monitors").mkdir(parents=True)
    env_file = (ROOT / "packaging" / "handler.env").read_text()
    if not re.search(r"^ROS_DOMAIN_ID=0$", env_file, re.M):
        raise AssertionError("packaging/handler.env no longer sets ROS_DOMAIN_ID=0")
    (work / "handler.env").write_text(
        env_file.replace("ROS_DOMAIN_ID=0\n", f"ROS_DOMAIN_ID={domain}\n")
    )
    shutil.copy(certs.crt, work / "handler.crt")
    shutil.copy(certs.key, work / "handler.key")
    (work / "monitors" / "robot.yaml").write_text(monitors)
    etc, data = tmp / "etc", tmp / "data"
    setup = with_values(readme_recipe("docker-setup"), {"ETC": str(etc), "DATA": str(data)})
    subprocess.run(["bash", "-euc", setup], cwd=work, check=True, timeout=60)
    return work, etc, data
