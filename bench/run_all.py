"""`make bench`: run every benchmark and write bench/RESULTS.md (numbers from one run)."""

from __future__ import annotations

import importlib
import os
import platform
import sys
from datetime import UTC, datetime
from pathlib import Path

BENCH = Path(__file__).resolve().parent
sys.path.insert(0, str(BENCH))
MODULES = [
    "evaluate",
    "ingest",
    "scale",
    "check_throughput",
    "check_bag",
    "check_jsonl",
    "timed_check",
    "nested_check",
    "migrate",
    "reactions",
    "planner",
    "fleet_round",
    "fleet_cloud",
]


def machine() -> str:
    cpu = "unknown CPU"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (
        f"{platform.system()} {platform.machine()}, {os.cpu_count()} cores, {cpu}, "
        f"Python {platform.python_version()}"
    )


def main() -> None:
    rows = []
    for name in MODULES:
        print(f"running bench/{name}.py ...", flush=True)
        rows += importlib.import_module(name).main()
    lines = [
        "# Benchmark results",
        "",
        f"Measured {datetime.now(UTC):%Y-%m-%d %H:%M} UTC on {machine()}.",
        "Each row's baseline and measurement ran side by side in one run; compare the ratios.",
        "",
        "| benchmark | workload | baseline | measured | ratio |",
        "|---|---|---|---|---|",
    ]
    lines += [
        f"| {r['name']} | {r['detail']} | {r['baseline']} | {r['measured']} | {r['ratio']} |"
        for r in rows
    ]
    (BENCH / "RESULTS.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
