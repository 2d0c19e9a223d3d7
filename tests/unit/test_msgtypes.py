"""The message definitions edgerv knows: the shipped Jazzy snapshot and rosbags' store."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from rosbags.typesys import Stores, get_typestore

from edgerv.core import msgtypes


def _plain(value: Any) -> Any:
    """rosbags' definitions as JSON gives them back (tuples as lists, node kinds as ints)."""
    return json.loads(json.dumps(value))


def test_the_shipped_snapshot_is_the_installed_rosbags_store() -> None:
    snapshot = json.loads(msgtypes.SNAPSHOT.read_text())
    assert snapshot["rosbags"] == msgtypes._rosbags_release() is not None, (
        "rosbags was upgraded: write the snapshot again with "
        '`python -c "from edgerv.core.msgtypes import write_snapshot; write_snapshot()"`'
    )
    assert snapshot["types"] == _plain(get_typestore(Stores.ROS2_JAZZY).fielddefs)
    loaded = msgtypes._snapshot()
    assert loaded is not None and _plain(loaded) == snapshot["types"]
    assert loaded["nav_msgs/msg/Odometry"][1][0] == ("header", (2, "std_msgs/msg/Header"))


def test_a_snapshot_of_another_rosbags_release_is_not_used(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    other = tmp_path / "jazzy_types.json"
    other.write_text(json.dumps({"rosbags": "0.0.1", "types": {"x/msg/Y": [[], []]}}))
    monkeypatch.setattr(msgtypes, "SNAPSHOT", other)
    assert msgtypes._snapshot() is None
    monkeypatch.setattr(msgtypes, "_known", None)
    assert "x/msg/Y" not in msgtypes.fielddefs()  # the store's own definitions instead
    assert msgtypes.field_kind("std_msgs/msg/Float64", "data") == "float"


def test_types_registered_reach_the_store_made_before_or_after(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(msgtypes, "_known", None)
    monkeypatch.setattr(msgtypes, "_store", None)
    assert msgtypes.register_definition("a_pkg/msg/Before", "ros2msg", "float64 value")
    store = msgtypes.typestore()  # made after the registration: it has the type
    assert "a_pkg/msg/Before" in store.fielddefs
    assert msgtypes.register_definition("a_pkg/msg/After", "ros2msg", "int32 count")
    assert "a_pkg/msg/After" in store.fielddefs and "a_pkg/msg/After" in msgtypes.fielddefs()
    assert msgtypes.field_kind("a_pkg/msg/After", "count") == "int"
    # decoded whole by the store
    payload = bytes([0, 1, 0, 0]) + (7).to_bytes(4, "little")
    assert store.deserialize_cdr(payload, "a_pkg/msg/After").count == 7
