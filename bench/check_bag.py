"""`edgerv check` on a robot's MCAP bag of 10 M events with 10 monitors, whole process
against whole process: the installed `edgerv` console script as a user runs it (output to
/dev/null) beside a Python process that only reads the same bag's messages with the `mcap`
package's stream reader (raw records, nothing decoded), each a process of its own, startup
included, the two in turn, three rounds, medians.

The bag (bench/robot_bag.py: /odom 50 Hz, /speed 100 Hz, /battery, /running, /estop, /stop
10 Hz; zstd chunks as `ros2 bag record` writes them) is written to a temporary directory
and removed after. Its size is ``EDGERV_BENCH_BAG_EVENTS`` (default 10,000,000; 100,000
for a smoke run).

Memory: the peak resident set of each check process, from the rusage ``os.wait4`` returns
for it (Linux ``ru_maxrss``: the process's own high-water mark, or that of a process it
started and waited for, if larger), on this bag and on a bag of its first tenth: streamed,
the two are about the same.
"""

from __future__ import annotations

import os
import shutil
import statistics
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from robot_bag import MONITORS, write_bag

EVENTS = int(os.environ.get("EDGERV_BENCH_BAG_EVENTS", "10000000"))
ROUNDS = 3
TARGET = 1_000_000  # events/s

# The baseline's whole job: open the bag and read every record with the `mcap` package's
# stream reader (chunks decompressed, nothing decoded), in file order (the bag's chunks are
# in log-time order: the order `edgerv check` reads them in), counting the messages. Its
# fastest complete read (`iter_messages` in log-time order took 1.5x as long).
BARE_READ = r"""
import sys
from mcap.records import Message
from mcap.stream_reader import StreamReader
with open(sys.argv[1], "rb") as f:
    print(sum(type(record) is Message for record in StreamReader(f).records))
"""


@dataclass
class Run:
    seconds: float  # wall clock, from spawning the process to reaping it
    code: int
    maxrss_mib: float
    stdout: str
    stderr: str


# Each process runs as a user's would: with Python's compiled bytecode cached beside the
# sources (an environment with PYTHONDONTWRITEBYTECODE, as some sandboxes set, would have
# every edgerv process compile its modules again: 0.1 s of each run, not a user's cost).
PROCESS_ENV = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}


def run_process(argv: list[str], keep_stdout: bool = False) -> Run:
    """Run ``argv`` (an absolute path first) as a process of its own; stdout to /dev/null
    unless kept. Its rusage comes from ``os.wait4``: its own, not the other children's."""
    with (
        tempfile.TemporaryFile() as out,
        tempfile.TemporaryFile() as err,
        open(os.devnull, "wb") as null,
    ):
        start = time.perf_counter()
        pid = os.posix_spawn(
            argv[0],
            argv,
            PROCESS_ENV,
            file_actions=[
                (os.POSIX_SPAWN_DUP2, (out if keep_stdout else null).fileno(), 1),
                (os.POSIX_SPAWN_DUP2, err.fileno(), 2),
            ],
        )
        _, status, usage = os.wait4(pid, 0)
        seconds = time.perf_counter() - start
        out.seek(0)
        err.seek(0)
        return Run(
            seconds,
            os.waitstatus_to_exitcode(status),
            usage.ru_maxrss / 1024,  # KiB on Linux
            out.read().decode(errors="replace"),
            err.read().decode(errors="replace"),
        )


def edgerv_command() -> str:
    """The `edgerv` console script of this environment, as a user runs it."""
    script = Path(sys.executable).parent / "edgerv"
    found = str(script) if script.exists() else shutil.which("edgerv")
    if found is None:
        raise RuntimeError("no edgerv console script beside this Python or on the PATH")
    return found


def checked(run: Run, what: str, codes: tuple[int, ...] = (0, 1)) -> Run:
    if run.code not in codes:
        raise RuntimeError(f"{what} exited {run.code}: {run.stderr[-2000:]}")
    return run


def main() -> list[dict[str, Any]]:
    edgerv = edgerv_command()
    with tempfile.TemporaryDirectory() as tmp:
        bag, small, monitors = (
            Path(tmp) / "run.mcap",
            Path(tmp) / "tenth.mcap",
            Path(tmp) / "m.yaml",
        )
        monitors.write_text(MONITORS)
        start = time.perf_counter()
        counts = write_bag(bag, EVENTS)
        generated = time.perf_counter() - start
        write_bag(small, EVENTS // 10)  # the first tenth of the same recording
        check_argv = [edgerv, "check", str(monitors), str(bag)]
        bare_argv = [sys.executable, "-c", BARE_READ, str(bag)]
        bare_s: list[float] = []
        check_s: list[float] = []
        rss: list[float] = []
        codes = set()
        for _ in range(ROUNDS):  # in turn: a burst of load elsewhere hits both alike
            bare = checked(run_process(bare_argv, keep_stdout=True), "the bare read", (0,))
            if int(bare.stdout) != EVENTS:
                raise RuntimeError(f"the bare read counted {bare.stdout.strip()} messages")
            bare_s.append(bare.seconds)
            run = checked(run_process(check_argv), "edgerv check")
            check_s.append(run.seconds)
            rss.append(run.maxrss_mib)
            codes.add(run.code)
        tenth = checked(run_process([edgerv, "check", str(monitors), str(small)]), "edgerv check")
        size = bag.stat().st_size / 2**20
    t_bare, t_check = statistics.median(bare_s), statistics.median(check_s)
    rate = EVENTS / t_check
    topics = ", ".join(f"{t} {c:,}" for t, c in counts.items())
    return [
        {
            "name": f"check of a robot's MCAP bag, 10 monitors (target >= {TARGET:,} events/s)",
            "detail": f"{EVENTS:,} events ({topics}; {size:,.0f} MiB, zstd chunks, written "
            f"in {generated:.0f} s), bench/robot_bag.py's 10 monitors (exit "
            f"{'/'.join(map(str, sorted(codes)))}); whole process each, startup included, "
            f"bare read and check in turn, median of {ROUNDS} "
            f"(check {', '.join(f'{s:.2f}' for s in check_s)} s)",
            "baseline": f"mcap reader alone {EVENTS / t_bare:,.0f} events/s ({t_bare:.2f} s)",
            "measured": f"edgerv check {rate:,.0f} events/s ({t_check:.2f} s), "
            f"peak RSS {max(rss):,.0f} MiB",
            "ratio": f"{rate / TARGET:.2f} of the target; {t_bare / t_check:.2f}x the bare "
            "read's speed",
        },
        {
            "name": "memory of edgerv check as the bag grows (target: bounded, streamed)",
            "detail": f"peak RSS of the check process (os.wait4's ru_maxrss: its own or a "
            f"child's high-water mark), the 10 monitors on the first {EVENTS // 10:,} events "
            f"and on all {EVENTS:,} of the same recording (all: the largest of {ROUNDS} runs; "
            "the tenth: one run)",
            "baseline": f"{EVENTS // 10:,} events: {tenth.maxrss_mib:,.0f} MiB",
            "measured": f"{EVENTS:,} events: {max(rss):,.0f} MiB",
            "ratio": f"{max(rss) / tenth.maxrss_mib:.2f}x the memory for 10x the events",
        },
    ]


if __name__ == "__main__":
    for row in main():
        print(row)
