"""The control API's 400 answers say what is wrong in the request's own terms: JSON, the
field named, the value as JSON writes it, never a Python repr (issue 38)."""

from __future__ import annotations

import json
import re
import urllib.error
import urllib.request
from collections.abc import Iterator
from typing import Any

import pytest
from prometheus_client import CollectorRegistry

from edgerv.handler.api import ControlApi
from edgerv.handler.engine import Engine

TOKEN = "answers-token"


@pytest.fixture
def api() -> Iterator[ControlApi]:
    served = ControlApi(
        Engine("answers", flush_after=1e9), CollectorRegistry(), TOKEN, lambda: None
    )
    served.start("127.0.0.1", 0)
    yield served
    served.stop()


def post(api: ControlApi, path: str, body: Any) -> tuple[int, dict[str, Any]]:
    request = urllib.request.Request(
        f"http://127.0.0.1:{api.port}{path}",
        data=json.dumps(body).encode(),
        headers={"Authorization": f"Bearer {TOKEN}", "Content-Type": "application/json"},
        method="POST",
    )
    try:
        with urllib.request.urlopen(request, timeout=10) as answer:
            return answer.status, json.loads(answer.read())
    except urllib.error.HTTPError as exc:
        return exc.code, json.loads(exc.read())


@pytest.mark.parametrize(
    ("body", "said"),
    [
        ({"epoch": 1}, 'missing field "monitors"'),
        ({"monitors": ["m"]}, 'missing field "epoch"'),
        ({"epoch": "one", "monitors": ["m"]}, 'epoch must be an integer, not "one"'),
        ({"epoch": [1] * 100, "monitors": ["m"]}, "epoch must be an integer, not [1, 1, "),
        ({"epoch": 1, "monitors": ["m"], "cuts": {"m": None}}, None),
        (["not", "an", "object"], "the body must be a JSON object"),
    ],
)
def test_a_bad_handoff_request_is_answered_in_its_own_terms(
    api: ControlApi, body: Any, said: str | None
) -> None:
    status, answer = post(api, "/v1/handoff/hold", body)
    assert status in (400, 409), answer
    (error,) = answer["errors"]
    message = error["message"]
    assert not re.search(r"\w+Error\(|\{'|\['", message), message  # no repr of Python's
    assert len(message) < 300
    if said is not None:
        assert said in message, message
