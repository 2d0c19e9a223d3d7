"""The Reelay peer of `edgerv check` (bench/check_jsonl.py): the whole job in a few lines.

Reads a JSON Lines trace with Python's json line by line, keeps the latest value of each
signal, and from the step where both have one feeds each event of /running or /speed to a
Reelay 25 discrete-time monitor; prints the number of violating steps. "Whenever running,
speed < 100" in Reelay's past-time syntax is `historically({running} -> {speed < 100})`;
a new monitor is started after each step where it is false, as edgerv's `onVerdict:
reset` restarts `always (running -> speed < 100)`, so the false steps counted are exactly
the steps where running holds and speed < 100 does not.
"""

import json
import sys

import reelay

PATTERN = "historically({running} -> {speed < 100})"
monitor, held, violations = reelay.discrete_timed_monitor(pattern=PATTERN, condense=False), {}, 0
with open(sys.argv[1]) as f:
    for line in f:
        event = json.loads(line)
        if event["topic"] in ("/running", "/speed"):
            held[event["topic"][1:]] = event["msg"]["data"]
            if len(held) == 2 and not monitor.update(held)["value"]:
                violations += 1
                monitor = reelay.discrete_timed_monitor(pattern=PATTERN, condense=False)
print(violations)
