"""Where ROS writes its log files, and what to do when it cannot.

rcl writes a log file per process under ``$ROS_LOG_DIR``, else ``$ROS_HOME/log``, else
``~/.ros/log``, and refuses to start when it cannot create that directory (a read-only
home in a hardened container, a service user without one): rclpy.init raises, which
is no fault of edgerv's and no fault of the user's monitors. edgerv's own log lines go
to stderr and /rosout whatever happens, so the file is not needed: where it cannot be
written, ROS is started without it (``--disable-external-lib-logs``) and one warning
says where it looked and which variable to set.
"""

from __future__ import annotations

import os
from pathlib import Path


def ros_log_dir(env: dict[str, str] | os._Environ[str] = os.environ) -> Path:
    """The directory rcl's file logging would use (rcl_logging_get_logging_directory)."""
    if env.get("ROS_LOG_DIR"):
        return Path(os.path.expanduser(env["ROS_LOG_DIR"]))
    if env.get("ROS_HOME"):
        return Path(os.path.expanduser(env["ROS_HOME"])) / "log"
    home = env.get("HOME") or os.path.expanduser("~")
    return Path(home) / ".ros" / "log"


def ros_log_problem(env: dict[str, str] | os._Environ[str] = os.environ) -> str | None:
    """None when rcl can write its log directory (creating it, as rcl would); else why
    not, with what to set."""
    where = ros_log_dir(env)
    try:
        where.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        reason = exc.strerror or type(exc).__name__
    else:
        if os.access(where, os.W_OK | os.X_OK):
            return None
        reason = "not writable"
    return (
        f"ROS cannot write its log files in {where} ({reason}): running without them "
        "(edgerv's log lines still go to stderr and /rosout); set ROS_LOG_DIR to a "
        "writable directory to have them"
    )
