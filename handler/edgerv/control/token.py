"""The control API's bearer token, as a value or as a file read again when it changes.

A Kubernetes Secret mounted as a volume is updated in place when it is rotated (the
kubelet swaps a symbolic link, within its sync period); the handler (``--token-file``)
and the operator (``EDGERV_TOKEN_FILE``) follow it without a restart. A file that
becomes unreadable or empty keeps the last token read, and says so once in the log.
"""

from __future__ import annotations

import logging
import os
import threading
import time
from pathlib import Path

log = logging.getLogger("edgerv.control.token")

CHECK_EVERY = 1.0  # seconds between two looks at the file (a stat, not a read)


class TokenFile:
    """A token kept in a file: :meth:`value` is the file's content, stripped, looked at
    again at most every ``check_every`` seconds and read again when it changed."""

    def __init__(self, path: str | os.PathLike[str], check_every: float = CHECK_EVERY) -> None:
        self.path = Path(path)
        self.check_every = check_every
        self._lock = threading.Lock()
        self._seen: tuple[int, int, int] | None = None  # inode, size, mtime of the last read
        self._checked = float("-inf")
        self._value = ""
        self._complained = False
        self.value()  # the first read: an unreadable or empty file raises here
        if not self._value:
            raise ValueError(f"{self.path}: the token file is empty")

    def __repr__(self) -> str:
        return f"TokenFile({str(self.path)!r})"

    def value(self) -> str:
        """The token now (raises OSError only on the first read)."""
        now = time.monotonic()
        with self._lock:
            if now - self._checked < self.check_every:
                return self._value
            self._checked = now
            try:
                st = self.path.stat()
                seen = (st.st_ino, st.st_size, st.st_mtime_ns)
                if seen != self._seen:
                    token = self.path.read_text(encoding="utf-8").strip()
                    if not token:
                        raise ValueError("it is empty")
                    if self._value and token != self._value:
                        log.info("%s: a new token (the old one is refused from now on)", self.path)
                    self._value, self._seen, self._complained = token, seen, False
            except (OSError, ValueError, UnicodeDecodeError) as exc:
                if not self._value:
                    raise
                if not self._complained:
                    log.warning("%s: cannot read the token (%s): keeping the last", self.path, exc)
                    self._complained = True
            return self._value


Token = str | TokenFile | None
"""What a client sends, or a server expects: a value, a file followed, or none."""


def current(token: Token) -> str | None:
    """The token's value now."""
    return token.value() if isinstance(token, TokenFile) else token
