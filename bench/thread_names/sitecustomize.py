"""Bench only (bench/edge_cost.py puts this directory on a measured process's PYTHONPATH):
each Python thread takes its name as the OS thread name (the first 15 bytes), so that
/proc/<pid>/task/<tid>/comm tells the handler's threads apart in a CPU split."""

from __future__ import annotations

import contextlib
import ctypes
import threading

_PR_SET_NAME = 15
_libc = ctypes.CDLL(None, use_errno=True)
_inner = threading.Thread._bootstrap_inner  # type: ignore[attr-defined]


def _named(self: threading.Thread) -> None:
    with contextlib.suppress(Exception):
        _libc.prctl(_PR_SET_NAME, self.name.encode()[:15], 0, 0, 0)
    _inner(self)


threading.Thread._bootstrap_inner = _named  # type: ignore[attr-defined]
