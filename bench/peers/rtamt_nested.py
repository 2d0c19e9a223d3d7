"""The RTAMT peer of `edgerv check` for a nested timed assertion (bench/nested_check.py):
reach the goal within 2 s, then stay there 500 ms, in RTAMT's dense-time STL (its best
tool for bounded future over recorded signals: whole signals, offline).

Reads the JSON Lines trace with Python's json line by line, keeps the latest value of
each signal and, from the first instant both have one, a sample where one changes (the
signals hold their values between messages, as edgerv reads them); evaluates the formula
once over the whole run and prints the number of stretches of time where it fails.
"""

import json
import sys

import rtamt

spec = rtamt.StlDenseTimeSpecification()
spec.declare_var("goal", "float")
spec.declare_var("at", "float")
spec.spec = (
    "(goal >= 0.5) implies "
    "(eventually[0:2000000000]((at >= 0.5) and (always[0:500000000](at >= 0.5))))"
)
spec.parse()
samples: dict[str, list[list[float]]] = {"goal": [], "at": []}
held: dict[str, float] = {}
t0 = None
with open(sys.argv[1]) as f:
    for line in f:
        event = json.loads(line)
        held[event["topic"][1:]] = float(event["msg"]["data"])
        if len(held) < 2:
            continue
        t0 = event["stamp"] if t0 is None else t0
        t = event["stamp"] - t0
        for name, value in held.items():
            s = samples[name]
            if s and s[-1][0] == t:
                s[-1][1] = value
            elif not s or s[-1][1] != value:
                s.append([t, value])
failures, last = 0, True
for _, robustness in spec.evaluate(["goal", samples["goal"]], ["at", samples["at"]]):
    if last and robustness < 0:
        failures += 1
    last = robustness >= 0
print(failures)
