"""A live handler monitors a service's events: a real rclpy service with introspection on
(Jazzy publishes each call's events on /<service>/_service_event), called by a real client,
its events read by `edgerv handler` with the sample-and-hold rule of docs/semantics.md
(section 2): a field inside an empty optional holds its signal's value."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

from kit.ros import HandlerProcess, ros_env, wait_for

pytestmark = pytest.mark.integration

SERVICE = "/switch"
EVENT_TOPIC = f"{SERVICE}/_service_event"

MONITORS = f"""\
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: every-switch-succeeds}}
spec:
  assertion: "always ok"
  signals:
    ok: {{topic: {EVENT_TOPIC}, type: lifecycle_msgs/srv/ChangeState_Event,
          field: "response[0].success"}}
---
apiVersion: edgerv.io/v1alpha1
kind: Monitor
metadata: {{name: never-transition-3}}
spec:
  assertion: "always (id != 3)"
  signals:
    id: {{topic: {EVENT_TOPIC}, type: lifecycle_msgs/srv/ChangeState_Event,
          field: "request[0].transition.id"}}
"""

# A service whose answer is success unless the transition's id is a multiple of 3, with
# introspection of its contents on; and a client calling it once for each id, in turn, once
# a subscriber (the handler's) is on the event topic.
SERVER_AND_CLIENT = r"""
import json, sys, time, rclpy
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rclpy.service_introspection import ServiceIntrospectionState
from lifecycle_msgs.srv import ChangeState
service, event_topic, ids = sys.argv[1], sys.argv[2], json.loads(sys.argv[3])
rclpy.init()
node = rclpy.create_node("switch_server")

def answer(request, response):
    response.success = request.transition.id % 3 != 0
    return response

srv = node.create_service(ChangeState, service, answer)
qos = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
srv.configure_introspection(node.get_clock(), qos, ServiceIntrospectionState.CONTENTS)
client = node.create_client(ChangeState, service)
deadline = time.monotonic() + 20
while node.count_subscribers(event_topic) == 0 and time.monotonic() < deadline:
    rclpy.spin_once(node, timeout_sec=0.05)
assert client.wait_for_service(timeout_sec=10)
for _ in range(10):  # the handler's subscription matched with the event publisher
    rclpy.spin_once(node, timeout_sec=0.05)
for i in ids:
    request = ChangeState.Request()
    request.transition.id = i
    future = client.call_async(request)
    rclpy.spin_until_future_complete(node, future, timeout_sec=10)
    assert future.done(), i
print("called", len(ids), flush=True)
end = time.monotonic() + 1.0
while time.monotonic() < end:
    rclpy.spin_once(node, timeout_sec=0.05)
"""


def held_violations(events: list[int | None]) -> list[int]:
    """The steps (1-based) at which ``always ok``-style monitors report violated: the value
    each event gives (None: the event has none, and the signal holds the one it had), a
    step from the first event after which the signal has a value; ``events`` as 1 (holds) or
    0 (fails). Computed here, independently of edgerv's pipeline."""
    held, step, out = None, 0, []
    for value in events:
        if value is not None:
            held = value
        if held is None:
            continue
        step += 1
        if not held:
            out.append(step)
    return out


def test_a_live_handler_monitors_a_services_requests_and_responses(
    tmp_path: Path, domain: int
) -> None:
    ids = [1, 2, 3, 4, 5, 6, 7, 9, 10, 11]
    monitors = tmp_path / "monitors.yaml"
    monitors.write_text(MONITORS)
    handler = HandlerProcess(tmp_path, monitors, domain)
    try:
        run = subprocess.run(
            [sys.executable, "-c", SERVER_AND_CLIENT, SERVICE, EVENT_TOPIC, json.dumps(ids)],
            env=ros_env(domain),
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert run.returncode == 0, run.stderr
        assert f"called {len(ids)}" in run.stdout
        wait_for(lambda: handler.metric("edgerv_messages_total", topic=EVENT_TOPIC) == 2 * len(ids))
    finally:
        assert handler.stop() == 0, handler.stderr
    # the server's events, in order: the request received (no response), the response sent
    # (no request), a call after the other
    responses: list[int | None] = []
    requests: list[int | None] = []
    for i in ids:
        responses += [None, int(i % 3 != 0)]
        requests += [int(i != 3), None]
    live: dict[str, list[int]] = {}
    for v in handler.verdicts():
        assert v["verdict"] == "violated", v
        live.setdefault(v["monitor"], []).append(v["step"])
    assert live == {
        "every-switch-succeeds": held_violations(responses),
        "never-transition-3": held_violations(requests),
    }, handler.stderr
    assert live["every-switch-succeeds"] and live["never-transition-3"]
