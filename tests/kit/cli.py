"""``edgerv`` as a user runs it, for tests: in this process (:func:`edgerv`: edgerv.cli.main,
its exit code, stdout and stderr, as a new process would see them) or as a process of its
own (:func:`edgerv_process`: what only a process shows: the exit codes 0, 1 and 2 through
os._exit, input that overflows a parser's stack, the progress bar on a terminal)."""

from __future__ import annotations

import contextlib
import io
import logging
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

from edgerv.cli import EXIT_INTERNAL, main
from edgerv.core import cdr, cdr_columns, msgtypes
from edgerv.core.language.spot_worker import worker


def edgerv_process(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """``edgerv ARGS`` as a user runs it: a process of its own (its exit code through
    os._exit, what reaches its stdout and stderr before it, a crash as a signal)."""
    return subprocess.run(
        [sys.executable, "-m", "edgerv", *map(str, args)],
        capture_output=True,
        text=True,
        timeout=120,
    )


def edgerv(*args: str | Path) -> subprocess.CompletedProcess[str]:
    """``edgerv ARGS`` run here, by edgerv.cli.main, as a new process would run it (the
    message types it knows start as the built-in ones; what it registers, its synthesis
    budget and a logging handler it adds are undone after): its exit code, stdout and
    stderr, without the 0.3 s of a new interpreter and its imports. An internal error
    (exit 70, its traceback by --debug) fails the test. The process itself (os._exit,
    a crash, a terminal) is :func:`edgerv_process`'s."""
    argv = ["--debug", *(str(a) for a in args)]
    out, err = io.StringIO(), io.StringIO()
    with (
        _as_a_new_process(),
        contextlib.redirect_stdout(out),
        contextlib.redirect_stderr(err),
    ):
        try:
            code = main(argv)
        except SystemExit as exc:  # argparse: a usage error, --version
            if exc.code is None or isinstance(exc.code, int):
                code = exc.code or 0
            else:  # as the interpreter does with sys.exit("text")
                print(exc.code, file=sys.stderr)
                code = 1
    if code == EXIT_INTERNAL:
        raise AssertionError(f"edgerv failed inside:\n{err.getvalue()}")
    return subprocess.CompletedProcess(["edgerv", *argv[1:]], code, out.getvalue(), err.getvalue())


def _forget_types() -> None:
    msgtypes._known = msgtypes._store = None  # fielddefs()/typestore() start over
    cdr._message_min_size.cache_clear()  # (their caches are by type name)
    cdr_columns._fixed_message.cache_clear()


@contextlib.contextmanager
def _as_a_new_process() -> Iterator[None]:
    saved = msgtypes._known, msgtypes._store, worker.budget
    root = logging.getLogger()
    handlers, level = root.handlers[:], root.level
    _forget_types()
    try:
        yield
    finally:
        _forget_types()
        msgtypes._known, msgtypes._store, worker.budget = saved
        root.handlers[:] = handlers
        root.setLevel(level)
