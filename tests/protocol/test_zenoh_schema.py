"""The published JSON Schema: current with the records, and agreeing with the Python decoder."""
from __future__ import annotations

import json

import jsonschema
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from protocol.zenoh import MalformedPayload, PayloadError, message_types
from protocol.zenoh.jsonschema import SCHEMA_DIR, payload_schemas, render
from test_zenoh_messages import json_values, messages

SCHEMAS = payload_schemas()
VALIDATORS = {name: jsonschema.Draft202012Validator(schema) for name, schema in SCHEMAS.items()}


def test_committed_schema_files_are_current():
    committed = {p.stem for p in SCHEMA_DIR.glob("*.json")}
    assert committed == set(message_types()), "run: python -m protocol.zenoh.jsonschema"
    for name, schema in SCHEMAS.items():
        jsonschema.Draft202012Validator.check_schema(schema)
        assert (SCHEMA_DIR / f"{name}.json").read_text() == render(schema), (
            f"{name}.json is stale: run python -m protocol.zenoh.jsonschema")


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages)
def test_every_valid_message_satisfies_its_schema(msg):
    VALIDATORS[msg.TYPE].validate(json.loads(msg.to_json()))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.data())
def test_what_the_schema_refuses_the_decoder_refuses(msg, data):
    """The schema is never more permissive than Python on shapes: a mutated payload the schema
    refuses is refused by the decoder too (the converse does not hold: cross-field rules)."""
    obj = json.loads(msg.to_json())
    key = data.draw(st.sampled_from(sorted(obj)))
    obj[key] = data.draw(json_values)
    if not VALIDATORS[msg.TYPE].is_valid(obj):
        with pytest.raises(PayloadError):
            type(msg).from_json(json.dumps(obj).encode())


def test_schema_names_the_envelope_and_forbids_unknown_fields():
    request = SCHEMAS["episode_request"]
    assert request["properties"]["type"] == {"const": "episode_request"}
    assert request["required"][:2] == ["v", "type"] and request["additionalProperties"] is False
    good = {"v": 1, "type": "episode_request", "episode_id": "e1", "task": "bracing", "theta": [0.5], "seed": 1}
    assert VALIDATORS["episode_request"].is_valid(good)
    for bad in ({**good, "extra": 1}, {**good, "seed": -1}, {**good, "episode_id": "e 1"},
                {**good, "task": "juggling"}, {k: v for k, v in good.items() if k != "seed"},
                {**good, "episode_id": "e1\n"}):
        assert not VALIDATORS["episode_request"].is_valid(bad), bad
        with pytest.raises(PayloadError):
            message_types()["episode_request"].from_json(json.dumps(bad))
    with pytest.raises(MalformedPayload):
        message_types()["episode_request"].from_json(json.dumps(good).replace("0.5", "NaN"))
