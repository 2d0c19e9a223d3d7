"""`edgerv check` throughput on a large recorded run, beside a bare read of the same file.

The ratio (check / bare read) is what monitoring costs on top of reading and
decoding the trace; both are measured in the same run on the same file.
"""

from __future__ import annotations

import json
import random
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests"))  # the tests' kit: the speed-limit run and its writer

from edgerv.core.checker import CheckRun  # noqa: E402
from edgerv.core.documents import load_monitors_text  # noqa: E402
from edgerv.core.monitor import compile_monitor  # noqa: E402
from edgerv.core.traces import Trace  # noqa: E402
from kit.speed_run import MONITORS, TYPES  # noqa: E402
from kit.traces import write_mcap  # noqa: E402

EVENTS = 200_000


def make_rows(n: int) -> list[tuple[str, int, dict[str, Any]]]:
    rng = random.Random(1)
    rows: list[tuple[str, int, dict[str, Any]]] = []
    stamp = 1_700_000_000_000_000_000
    for i in range(n):
        stamp += rng.randint(0, 2_000_000)
        r = rng.random()
        if r < 0.7:
            rows.append(("/speed", stamp, {"data": rng.uniform(0, 105)}))
        elif r < 0.85:
            rows.append(("/running", stamp, {"data": rng.random() < 0.9}))
        elif r < 0.95:
            rows.append(("/stop", stamp, {"data": rng.random() < 0.1}))
        else:
            sec, ns = divmod(stamp, 1_000_000_000)
            rows.append(
                (
                    "/target",
                    stamp,
                    {
                        "header": {"stamp": {"sec": sec, "nanosec": ns}, "frame_id": "map"},
                        "point": {"x": i / n * 10, "y": 0.0, "z": 0.0},
                    },
                )
            )
    return rows


def timed(fn: Callable[[], int]) -> tuple[float, int]:
    start = time.perf_counter()
    n = fn()
    return time.perf_counter() - start, n


def main() -> list[dict[str, Any]]:
    specs = load_monitors_text("bench.yaml", MONITORS)
    monitors = [compile_monitor(s) for s in specs]
    topics = {"/speed", "/running", "/stop", "/target"}
    fields = CheckRun(monitors).fields()  # a bag's fields, read as `edgerv check` reads them
    results = []
    with tempfile.TemporaryDirectory() as tmp:
        rows = make_rows(EVENTS)
        jsonl = Path(tmp) / "run.jsonl"
        jsonl.write_text(
            "".join(json.dumps({"topic": t, "stamp": s, "msg": m}) + "\n" for t, s, m in rows)
        )
        mcap = write_mcap(Path(tmp) / "run.mcap", rows, TYPES)
        for label, path in (("JSON Lines", jsonl), ("MCAP bag", mcap)):

            def bare(path: Path = path) -> int:
                return sum(map(len, Trace(path).events(topics, fields=fields).chunks()))

            def check(path: Path = path) -> int:
                run = CheckRun(monitors)
                run.feed(Trace(path).events(run.topics, fields=fields))
                return sum(len(r.verdicts) for r in run.finish())

            t_bare, n = timed(bare)
            t_check, verdicts = timed(check)
            results.append(
                {
                    "name": f"check throughput, {label}",
                    "detail": f"{n} events, 2 monitors, {verdicts} verdicts",
                    "baseline": f"bare read {n / t_bare:,.0f} events/s",
                    "measured": f"check {n / t_check:,.0f} events/s",
                    "ratio": f"{t_bare / t_check:.2f} of bare read speed",
                }
            )
    return results


if __name__ == "__main__":
    for r in main():
        print(r)
