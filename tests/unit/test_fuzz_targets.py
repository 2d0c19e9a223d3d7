"""The coverage-guided fuzz targets (tests/fuzz/, atheris): bounded runs, and their crashes.

Each target runs here for 500 inputs beyond its checked-in seed
corpus (``make fuzz`` runs each for ``FUZZ_SECONDS``), and every input a fuzzer
ever crashed or hung on, checked in under ``tests/fuzz/crashes/<target>/``, is
replayed through the target in-process: each stays fixed.
"""

from __future__ import annotations

import importlib.util
import subprocess
import sys
from pathlib import Path
from types import ModuleType

import pytest

from kit.bounded import bounded

FUZZ = Path(__file__).resolve().parents[1] / "fuzz"
TARGETS = ["cdr", "bundle", "assertion", "api"]
RUNS = 500  # 2000 before stop 35 (the unit tier's minute); make fuzz runs each for FUZZ_SECONDS
DICTS = {name: [f"-dict={FUZZ / name}.dict"] for name in ("bundle", "assertion", "api")}


def target(name: str) -> ModuleType:
    spec = importlib.util.spec_from_file_location(f"fuzz_{name}", FUZZ / f"fuzz_{name}.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def inputs(kind: str) -> list[Path]:
    return sorted(p for p in (FUZZ / kind).glob("*/*") if p.is_file() and p.name != ".gitkeep")


@pytest.mark.parametrize("name", TARGETS)
def test_each_fuzz_target_runs_clean_for_a_few_hundred_inputs(name: str, tmp_path: Path) -> None:
    pytest.importorskip("atheris")
    # new inputs go to a scratch corpus (the first directory), never to the checked-in one
    work = tmp_path / "corpus"
    work.mkdir()
    run = subprocess.run(
        [sys.executable, str(FUZZ / f"fuzz_{name}.py"), f"-runs={RUNS}", "-seed=1",
         "-timeout=20", f"-artifact_prefix={tmp_path}/", *DICTS.get(name, []),
         str(work), str(FUZZ / "corpus" / name)],
        capture_output=True, text=True, timeout=300,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-4000:]
    assert f"Done {RUNS} runs" in run.stderr or "DONE" in run.stderr, run.stderr[-2000:]


@pytest.mark.parametrize("path", inputs("crashes"), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_every_input_a_fuzzer_crashed_on_stays_fixed(path: Path) -> None:
    with bounded(10):
        target(path.parent.name).fuzz_one_input(path.read_bytes())


@pytest.mark.parametrize("name", TARGETS)
def test_the_seeds_are_real_inputs(name: str) -> None:
    """Each seed reads without error: after a change of a message definition, of the wire
    form or of the assertion language, a stale seed would leave the fuzzer to start from
    nothing (make_corpus.py; the assertions are written by hand: each compiles)."""
    from edgerv.core.handoff import bundle, decode, unbundle

    module = target(name)
    seeds = [p for p in inputs("corpus") if p.parent.name == name]
    assert seeds
    module.load()
    with bounded(20):
        for path in seeds:
            data = path.read_bytes()
            if name == "cdr":
                module._readers[data[0]](data[1:])
            elif name == "assertion":
                assert module.compiles(data.decode()), data
            elif name == "api":  # each an HTTP request the API answers (2xx, 3xx, 4xx)
                assert data[1:].startswith((b"GET ", b"POST ", b"PUT ", b"DELETE ")), data
            else:
                mode, rest = data[0], data[2:]
                frames = (
                    [module.framed(rest)] if mode == 3
                    else [rest] if mode == 1
                    else unbundle(rest if mode == 0 else bundle([rest]))
                )  # fmt: skip
                assert all(decode(frame).monitor == "m" for frame in frames)
            module.fuzz_one_input(data)
