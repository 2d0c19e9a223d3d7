"""Monitor documents for tests, built from Python values: a document as a dict
(:func:`monitor_doc`), as YAML text (:func:`monitor_yaml`; one over the robot's /speed:
:func:`speed_monitor`; several in one file: :func:`monitors_yaml`), loaded
(:func:`spec_of`) or compiled (:func:`compiled`); and :func:`write`, a file of them in a
test's directory. A test whose point is a document's exact text (an error located at its
line and column) writes that text itself."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from edgerv.core.documents import MonitorSpec, load_monitors_text
from edgerv.core.monitor import CompiledMonitor, compile_monitor

TYPES = {
    "bool": "std_msgs/msg/Bool",
    "float": "std_msgs/msg/Float64",
    "int": "std_msgs/msg/Int32",
    "string": "std_msgs/msg/String",
}


def monitor_doc(name: str, assertion: str, signals: dict[str, Any], **spec: Any) -> dict[str, Any]:
    """A Monitor document; a signal given as a kind name ('bool', 'float', ...) reads /<name>."""
    sigs = {}
    for sname, sig in signals.items():
        sigs[sname] = {"topic": f"/{sname}", "type": TYPES[sig]} if isinstance(sig, str) else sig
    return {
        "apiVersion": "edgerv.io/v1alpha1",
        "kind": "Monitor",
        "metadata": {"name": name},
        "spec": {"assertion": assertion, "signals": sigs, **spec},
    }


# libyaml's emitter when PyYAML has it: the same text as the pure-Python one (a fifth of
# the time), and thousands of monitors are built here
_DUMPER = getattr(yaml, "CSafeDumper", yaml.SafeDumper)


def spec_of(assertion: str, signals: dict[str, Any], name: str = "m", **spec: Any) -> MonitorSpec:
    doc = monitor_doc(name, assertion, signals, **spec)
    text = yaml.dump(doc, Dumper=_DUMPER, sort_keys=False)
    return load_monitors_text("test.yaml", text)[0]


def compiled(assertion: str, signals: dict[str, Any], **spec: Any) -> CompiledMonitor:
    return compile_monitor(spec_of(assertion, signals, **spec))


def monitor_yaml(name: str, assertion: str, signals: dict[str, Any], **spec: Any) -> str:
    """A Monitor document as YAML text, as a user writes it in a file (``signals`` as
    :func:`monitor_doc` takes them; ``spec``: the rest of its spec, in order)."""
    return str(
        yaml.dump(monitor_doc(name, assertion, signals, **spec), Dumper=_DUMPER, sort_keys=False)
    )


def speed_monitor(name: str, assertion: str = "always (speed < 100)", **spec: Any) -> str:
    """A Monitor over ``speed``, the robot's speed on /speed (std_msgs/msg/Float64), as
    YAML text; by default a cap of 100."""
    return monitor_yaml(name, assertion, {"speed": "float"}, **spec)


def monitors_yaml(*docs: str) -> str:
    """Monitor documents (YAML text) in one file, ``---`` between them."""
    return "---\n".join(docs)


def write(tmp: Path, name: str, text: str) -> Path:
    """The file ``name`` in ``tmp``, holding ``text`` (Monitor documents, most often)."""
    path = tmp / name
    path.write_text(text)
    return path
