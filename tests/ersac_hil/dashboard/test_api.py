"""Control bodies are refused exactly as the protocol refuses them; errors map to HTTP."""
from __future__ import annotations

import json

import pytest
from hypothesis import given
from hypothesis import strategies as st

from ersac_hil.daemon.clients import NoAnswer, RequestRefused
from ersac_hil.dashboard import api
from protocol.zenoh import KAPPA_MAX, KAPPA_MIN, ErrorReply, LearnerState, PayloadError, get_task

BRACING = get_task("bracing")
STATE = LearnerState("run-1", "bracing", "running", (0.5,), (0.1,), 1.0, dict(BRACING.default_weights), 3)
JSON = "application/json"


def _status(exc: Exception) -> int:
    return api.error_from_exception(exc).status


@given(st.floats(allow_nan=False, allow_infinity=False))
def test_kappa_accepted_exactly_in_range(kappa):
    body = api.parse_body(json.dumps({"kappa": kappa}).encode(), JSON)
    if KAPPA_MIN <= kappa <= KAPPA_MAX:
        assert api.kappa_command(body).kappa == kappa
    else:
        with pytest.raises(PayloadError) as info:
            api.kappa_command(body)
        error = api.error_from_exception(info.value)
        assert (error.status, error.field) == (400, "kappa")


@pytest.mark.parametrize("body", [{}, {"kappa": True}, {"kappa": "1"}, {"kappa": None}, {"kappa": [1]},
                                  {"kappa": 1, "extra": 2}])
def test_kappa_bodies_refused(body):
    with pytest.raises(PayloadError) as info:
        api.kappa_command(body)
    assert _status(info.value) == 400


@pytest.mark.parametrize("raw, content_type, status", [
    (b'{"kappa": 1}', "text/plain", 415),
    (b'{"kappa": 1}', None, 415),
    (b'{"kappa": NaN}', JSON, 400),
    (b'{"kappa": 1, "kappa": 2}', JSON, 400),
    (b'[1]', JSON, 400),
    (b'\xff', JSON, 400),
])
def test_bodies_that_are_not_one_strict_json_object(raw, content_type, status):
    with pytest.raises(Exception) as info:
        api.parse_body(raw, content_type)
    assert _status(info.value) == status
    assert api.parse_body(b'{"kappa": 1}', "application/json; charset=utf-8") == {"kappa": 1}


def test_weights_need_known_terms_and_non_negative_values():
    assert dict(api.weights_command({"weights": {"arm_power": 20}}, STATE).weights) == {"arm_power": 20.0}
    for body, field in (({"weights": {"energy": 1.0}}, "weights.energy"),
                        ({"weights": {"arm_power": -1.0}}, "weights.arm_power"),
                        ({"weights": {}}, "weights"), ({"weights": {"arm_power": None}}, "weights.arm_power")):
        with pytest.raises(PayloadError) as info:
            api.weights_command(body, STATE)
        error = api.error_from_exception(info.value)
        assert (error.status, error.field) == (400, field)


def test_select_query_carries_adopt_and_checks_its_fields():
    query = api.select_query({"kappa": 2.0, "weights": {"damage": 20}}, STATE, adopt=True)
    assert (query.kappa, dict(query.weights), query.adopt) == (2.0, {"damage": 20.0}, True)
    assert api.select_query({"kappa": -1}, STATE, adopt=False).adopt is False
    for body in ({}, {"kappa": 11}, {"kappa": 1, "adopt": True}, {"kappa": 1, "weights": {"x": 1}}):
        with pytest.raises(PayloadError):
            api.select_query(body, STATE, adopt=False)


def test_learner_answers_map_to_http():
    def refused(code: str) -> int:
        return _status(RequestRefused(ErrorReply(code, "why")))
    assert (refused("invalid_request"), refused("unavailable"), refused("busy"), refused("internal")) \
        == (400, 409, 503, 502)
    assert _status(NoAnswer("gone")) == 504
    assert api.FORBIDDEN.status == 403 and api.FORBIDDEN.body()["error"]["code"] == "forbidden"
    with pytest.raises(ZeroDivisionError):  # a bug is not an answer: it propagates
        api.error_from_exception(ZeroDivisionError())
