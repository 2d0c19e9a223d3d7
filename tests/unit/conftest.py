"""Fixtures that several modules of the unit tier use (their builders: tests/kit)."""

from __future__ import annotations

from collections.abc import Iterator

import pytest
from prometheus_client import CollectorRegistry

from edgerv.handler.api import ControlApi
from kit.engines import robot_feed
from kit.handoff_pair import TOKEN, Gate, Pair, edge_and_cloud


@pytest.fixture
def pair() -> Iterator[Pair]:
    edge, cloud = edge_and_cloud()
    apis = []
    for e in (edge, cloud):
        api = ControlApi(e, CollectorRegistry(), TOKEN, on_change=lambda: None)
        api.start("127.0.0.1", 0)
        apis.append(api)
    gate = Gate(apis[1].port)
    with robot_feed([edge, cloud]):  # both hosts hear the robot's two topics
        yield Pair(edge, cloud, apis, gate)
    gate.close()
    for api in apis:
        api.stop()
