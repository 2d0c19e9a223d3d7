"""The memory budget at the control API (docs/handler.md, "Limits on input"): a monitor
whose buffers would pass what the budget leaves the monitors is refused with a 403 that
says so at ``spec.bufferCapacity``; a POST of several is all or nothing; a monitor
removed gives its share back. (The budget's arithmetic: tests/unit/test_memory_budget.py.)
"""

from __future__ import annotations

import json
from collections.abc import Iterator

import pytest
from prometheus_client import CollectorRegistry

from edgerv.control.client import HandlerClient
from edgerv.core.documents import load_monitors_text
from edgerv.handler.api import ControlApi
from edgerv.handler.budget import MemoryBudget, MiB, Shares, monitor_cost
from edgerv.handler.engine import Engine

TOKEN = "budget-token"
ROOM = 8 * MiB  # what the budget leaves the monitors


def document(name: str, capacity: int) -> bytes:
    return (
        "apiVersion: edgerv.io/v1alpha1\nkind: Monitor\n"
        f"metadata: {{name: {name}}}\n"
        "spec:\n"
        '  assertion: "always (x < 5)"\n'
        "  signals:\n"
        "    x: {topic: /x, type: std_msgs/msg/Float64, field: data}\n"
        f"  bufferCapacity: {capacity}\n"
    ).encode()


def cost(capacity: int) -> int:
    return monitor_cost(load_monitors_text("m.yaml", document("m", capacity).decode())[0])


@pytest.fixture
def api() -> Iterator[ControlApi]:
    engine = Engine("budget", flush_after=1e9)
    engine.budget = MemoryBudget(ROOM + 4 * MiB, Shares(MiB, MiB, MiB, MiB))
    served = ControlApi(engine, CollectorRegistry(), TOKEN, lambda: None)
    served.start("127.0.0.1", 0)
    yield served
    served.stop()


def test_a_monitor_over_the_budget_is_refused_at_its_buffer_capacity(api: ControlApi) -> None:
    h = HandlerClient(f"127.0.0.1:{api.port}", TOKEN)
    small, huge = 4096, 10_000_000
    assert cost(small) < ROOM < cost(huge)
    assert h.call("/v1/monitors", raw=document("a", small))[0] == 201
    status, body = h.call("/v1/monitors", raw=document("b", huge))
    assert status == 403
    error = json.loads(body)["errors"][0]
    assert error["message"].startswith(
        "spec.bufferCapacity: monitor 'b' would pass this handler's memory budget: it would "
        "take about "
    ), error
    assert "a smaller bufferCapacity, another handler, or a larger budget" in error["message"]
    assert sorted(api.engine.slots) == ["a"]
    # two that fit alone but not together: neither is added
    half = next(c for c in range(small, huge, 50_000) if cost(c) > ROOM // 2)
    both = document("c", half) + b"\n---\n" + document("d", half)
    assert h.call("/v1/monitors", raw=both)[0] == 403
    assert sorted(api.engine.slots) == ["a"]
    assert h.call("/v1/monitors", raw=document("c", half))[0] == 201
    assert h.call("/v1/monitors", raw=document("d", half))[0] == 403
    assert h.call("/v1/monitors/c", method="DELETE")[0] == 200  # its share given back
    assert h.call("/v1/monitors", raw=document("d", half))[0] == 201
    h.close()
