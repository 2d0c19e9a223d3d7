"""Where rcl writes its log files, and the warning when it cannot (handler/ros/logs.py).

The handler and `edgerv replay` start ROS without its log files where that directory
cannot be written (a read-only home), instead of failing at rclpy.init with exit 70
(tests/integration/test_unwritable_home.py runs the handler so)."""

from __future__ import annotations

from pathlib import Path

from edgerv.handler.ros.logs import ros_log_dir, ros_log_problem


def test_the_directory_is_resolved_as_rcl_resolves_it(tmp_path: Path) -> None:
    home = str(tmp_path)
    assert ros_log_dir({"HOME": home}) == tmp_path / ".ros" / "log"
    assert ros_log_dir({"HOME": home, "ROS_HOME": f"{home}/r"}) == tmp_path / "r" / "log"
    both = {"HOME": home, "ROS_HOME": f"{home}/r", "ROS_LOG_DIR": f"{home}/l"}
    assert ros_log_dir(both) == tmp_path / "l"


def test_a_writable_home_gets_its_directory_and_no_warning(tmp_path: Path) -> None:
    assert ros_log_problem({"HOME": str(tmp_path)}) is None
    assert (tmp_path / ".ros" / "log").is_dir()


def test_a_home_that_is_a_file_is_said_with_the_variable_to_set(tmp_path: Path) -> None:
    home = tmp_path / "file"
    home.write_text("")
    problem = ros_log_problem({"HOME": str(home)})
    assert problem == (
        f"ROS cannot write its log files in {home}/.ros/log (Not a directory): running "
        "without them (edgerv's log lines still go to stderr and /rosout); set ROS_LOG_DIR "
        "to a writable directory to have them"
    )
    assert ros_log_problem({"HOME": str(home), "ROS_LOG_DIR": str(tmp_path / "l")}) is None
