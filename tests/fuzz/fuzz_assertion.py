"""Coverage-guided fuzzing (atheris, libFuzzer) of the assertion parser.

A Monitor's assertion comes from a file or a ``POST /v1/monitors``: any text can
arrive. Compiling it (``edgerv.core.monitor.compile_monitor``: the parser of
``edgerv.core.language.assertion``, the past and time-bounded operators, Spot's synthesis
under its budget) must return a monitor, or raise ``InputError`` whose every
diagnostic is located inside the assertion; never another exception, and quickly.
An input is the assertion's text (UTF-8, undecodable bytes replaced), over a fixed
set of signals of every kind and parameters of extreme values (:data:`SIGNALS`,
:data:`PARAMETERS`); ``assertion.dict`` holds the language's words::

    python tests/fuzz/fuzz_assertion.py WORK_CORPUS tests/fuzz/corpus/assertion \
        -dict=tests/fuzz/assertion.dict -max_total_time=60

``make fuzz`` runs it (``FUZZ_SECONDS``); ``tests/unit/test_fuzz_targets.py`` runs
it for a couple of thousand inputs and replays every input in
``tests/fuzz/crashes/assertion/`` through :func:`fuzz_one_input`.
tests/unit/test_assertion_grammar.py checks the same property from a grammar.
"""

from __future__ import annotations

import dataclasses
import importlib
import math
import sys
from typing import Any

SIGNALS = {
    "a": "std_msgs/msg/Bool",
    "b": "std_msgs/msg/Bool",
    "go": "std_msgs/msg/Bool",
    "done": "std_msgs/msg/Bool",
    "busy": "std_msgs/msg/Bool",
    "ok": "std_msgs/msg/Bool",
    "n": "std_msgs/msg/Int64",
    "u": "std_msgs/msg/UInt8",
    "x": "std_msgs/msg/Float64",
    "y": "std_msgs/msg/Float32",
    "s": "std_msgs/msg/String",
    "GF": "std_msgs/msg/Bool",  # Spot's compact GF p, and a name (not reserved)
    "ms": "std_msgs/msg/Int64",  # a unit, and a name
}
PARAMETERS: dict[str, Any] = {
    "lim": 3,
    "neg": -7,
    "inf": math.inf,
    "ninf": -math.inf,
    "huge": 10**400,
    "tiny": 5e-324,
    "big": 1e308,
    "name": "AUTO",
    "flag": True,
}
BUDGET = 2.0  # seconds of Spot per monitor when fuzzing (libFuzzer's -timeout is 10 s)
MAX_CHARS = 1 << 14

_spec: list[Any] = []


def load() -> None:
    """The Monitor every input's assertion is put into (through YAML, as a file gives it)."""
    import yaml

    from edgerv.core.documents import load_monitors_text

    doc = {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": "m"},
        "spec": {
            "assertion": "a",
            "signals": {n: {"topic": f"/{n}", "type": t} for n, t in SIGNALS.items()},
            "parameters": PARAMETERS,
        },
    }
    _spec.append(load_monitors_text("m.yaml", yaml.safe_dump(doc))[0])


def compiles(text: str) -> bool:
    """True if ``text`` compiles over the signals and parameters, False if it is refused
    with every diagnostic located in it; anything else raises."""
    from edgerv.core.diagnostics import InputError, Location
    from edgerv.core.monitor import compile_monitor

    if not _spec:
        load()
    placed: list[Location] = []

    def locate(offset: int, length: int) -> Location:
        if not (0 <= offset <= len(text) and length >= 1):
            raise AssertionError(f"located at {offset}+{length} in {len(text)} characters")
        placed.append(Location("assertion", 1, offset + 1, length, text))
        return placed[-1]

    spec = dataclasses.replace(_spec[0], assertion=text, locate_assertion=locate)
    try:
        monitor = compile_monitor(spec)
    except InputError as exc:
        if not exc.errors or any(d.location not in placed for d in exc.diagnostics):
            raise AssertionError(f"not located in the assertion: {exc}") from exc
        return False
    if any(d.location not in placed for d in monitor.warnings):
        raise AssertionError(f"a warning not located in the assertion: {monitor.warnings}")
    return True


def fuzz_one_input(data: bytes) -> None:
    compiles(data[:MAX_CHARS].decode("utf-8", "replace"))


def main() -> None:
    import atheris

    from edgerv.core.language.spot_worker import worker

    worker.budget = BUDGET  # (this process only: a replay in the unit tier keeps its own)
    with atheris.instrument_imports(include=["edgerv"]):
        for module in ("edgerv.core.language", "edgerv.core.monitor"):
            importlib.import_module(module)
        load()
    atheris.Setup(sys.argv, fuzz_one_input)
    atheris.Fuzz()


if __name__ == "__main__":
    main()
