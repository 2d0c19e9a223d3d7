"""The RTAMT peer of `edgerv check` (bench/check_jsonl.py): the whole job in a few lines.

Reads a JSON Lines trace with Python's json line by line, keeps the latest value of each
signal, and from the step where both have one feeds each event of /running or /speed to an
RTAMT discrete-time online monitor; prints the number of violating steps. "Whenever
running, speed < 100" in RTAMT's past-time STL is `historically((running >= 0.5) implies
(speed < 100))` (running as 1.0 or 0.0); a negative robustness is a violation, and the
monitor is reset after each, as edgerv's `onVerdict: reset` restarts `always (running ->
speed < 100)`, so the steps counted are exactly those where running holds and speed < 100
does not (a speed of exactly 100 has robustness 0, which RTAMT does not count: the bench's
speeds never are exactly 100).
"""

import json
import sys

import rtamt

spec = rtamt.StlDiscreteTimeSpecification()
spec.declare_var("running", "float")
spec.declare_var("speed", "float")
spec.spec = "historically((running >= 0.5) implies (speed < 100))"
spec.parse()
held, step, violations = {}, 0, 0
with open(sys.argv[1]) as f:
    for line in f:
        event = json.loads(line)
        if event["topic"] in ("/running", "/speed"):
            held[event["topic"][1:]] = float(event["msg"]["data"])
            if len(held) == 2:
                if spec.update(step, list(held.items())) < 0:
                    violations += 1
                    spec.reset()
                step += 1
print(violations)
