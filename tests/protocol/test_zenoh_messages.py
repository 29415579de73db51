"""Payload schemas: exact round trips, and every kind of garbage raising a typed PayloadError.

The garbage tests call ``from_json``/``decode`` directly: any exception other than a
``PayloadError`` subclass fails the test, so a bare KeyError/TypeError/ValueError escaping
the decoder is caught here.
"""
from __future__ import annotations

import json
import math
import pickle
import re
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from protocol.zenoh import (
    AGENT_PHASES,
    CHUNK_PATTERN,
    AgentState,
    EstopCommand,
    ERROR_CODES,
    FAILURE_FLAGS,
    GRID_MAX,
    KAPPA_MAX,
    KAPPA_MIN,
    LEARNER_STATUSES,
    MAX_CRITIC_POINTS,
    MAX_PAYLOAD_BYTES,
    SEED_MAX,
    STATUSES,
    TASKS,
    CriticPoint,
    CriticQuery,
    CriticReply,
    EpisodeDone,
    EpisodeRequest,
    EpisodeResult,
    ErrorReply,
    InvalidField,
    KappaCommand,
    LearnerEpisode,
    LearnerState,
    MalformedPayload,
    Message,
    PayloadError,
    PayloadTooLarge,
    SelectQuery,
    SelectReply,
    UnsupportedVersion,
    WeightsCommand,
    decode,
    message_types,
)
from protocol.zenoh import codec
from protocol.zenoh.codec import ID_PATTERN, NAME_PATTERN
from protocol.zenoh.keys import CHUNK_PATTERN
from protocol.zenoh.tasks import weighted_total

# --------------------------------------------------------------------------- strategies

ids = st.from_regex(ID_PATTERN, fullmatch=True)
names = st.from_regex(NAME_PATTERN, fullmatch=True)
finite = st.floats(allow_nan=False, allow_infinity=False)
moderate = st.floats(-1e6, 1e6, allow_nan=False)
nonneg = st.floats(0.0, 1e6, allow_nan=False)
kappas = st.floats(KAPPA_MIN, KAPPA_MAX, allow_nan=False)
task_names = st.sampled_from(sorted(TASKS))
stamps = st.floats(0.0, 4e9, allow_nan=False)


def thetas(task: str):
    spec = TASKS[task]
    return st.tuples(*(st.floats(lo, hi, allow_nan=False) for lo, hi in zip(spec.lower, spec.upper)))


def weights(task: str):
    return st.fixed_dictionaries({n: nonneg for n in TASKS[task].term_names})


@st.composite
def episode_requests(draw, task=None):
    task = task or draw(task_names)
    return EpisodeRequest(draw(ids), task, draw(thetas(task)), draw(st.integers(0, SEED_MAX)))


@st.composite
def episode_results(draw, episode_id=None, task=None):
    task = task or draw(task_names)
    status = draw(st.sampled_from(STATUSES))
    terms = TASKS[task].term_names
    if status == "ok":
        cost_terms = draw(st.fixed_dictionaries({n: finite for n in terms}))
        total = draw(finite)
    else:
        cost_terms = draw(st.dictionaries(st.sampled_from(terms), finite))
        total = None
    return EpisodeResult(
        episode_id=episode_id or draw(ids),
        task=task,
        status=status,
        cost_terms=cost_terms,
        total_cost=total,
        failures=draw(st.dictionaries(st.sampled_from(FAILURE_FLAGS), st.booleans())),
        duration_s=draw(st.floats(0, 86_400, allow_nan=False)),
        wall_s=draw(st.floats(0, 86_400, allow_nan=False)),
        telemetry=draw(st.dictionaries(names, finite, max_size=6)),
        fault_counts=draw(st.dictionaries(names, st.integers(0, 2**53), max_size=4)),
        detail=draw(st.text(max_size=50)),
        trace=draw(st.just("") | ids.map(lambda i: i[:120] + draw(st.sampled_from([".blf", ".asc"])))),
    )


@st.composite
def episode_dones(draw):
    req = draw(episode_requests())
    res = draw(episode_results(req.episode_id, req.task))
    return EpisodeDone(draw(st.from_regex(CHUNK_PATTERN, fullmatch=True)), draw(stamps), req, res)


@st.composite
def learner_states(draw):
    task = draw(task_names)
    dim = TASKS[task].dim
    return LearnerState(
        run_id=draw(ids),
        task=task,
        status=draw(st.sampled_from(LEARNER_STATUSES)),
        theta=draw(thetas(task)),
        sigma=draw(st.lists(st.floats(1e-9, 10.0), min_size=dim, max_size=dim)),
        kappa=draw(kappas),
        weights=draw(weights(task)),
        episode_count=draw(st.integers(0, 10**9)),
    )


@st.composite
def critic_replies(draw):
    task = draw(task_names)
    kappa = draw(kappas)
    points = []
    for _ in range(draw(st.integers(1, 5))):
        j, r = draw(moderate), draw(nonneg)
        points.append(CriticPoint(draw(thetas(task)), j, r, j + kappa * r))
    return CriticReply(task, kappa, tuple(points))


@st.composite
def select_replies(draw):
    task = draw(task_names)
    kappa, j, r = draw(kappas), draw(moderate), draw(nonneg)
    return SelectReply(task, draw(thetas(task)), j, r, j + kappa * r, kappa, draw(weights(task)),
                       draw(st.booleans()))


@st.composite
def learner_episodes(draw):
    req = draw(episode_requests())
    res = draw(episode_results(req.episode_id, req.task))
    dim = req.spec.dim
    return LearnerEpisode(
        run_id=draw(ids),
        index=draw(st.integers(0, 10**6)),
        base_theta=draw(thetas(req.task)),
        z=draw(st.lists(moderate, min_size=dim, max_size=dim)),
        request=req,
        result=res,
        cost=draw(finite) if res.ok else None,
        stamp_s=draw(stamps),
    )


messages = st.one_of(
    episode_requests(),
    episode_results(),
    episode_dones(),
    learner_states(),
    critic_replies(),
    select_replies(),
    learner_episodes(),
    st.builds(KappaCommand, kappas),
    st.builds(WeightsCommand, st.dictionaries(names, nonneg, min_size=1, max_size=8)),
    st.builds(ErrorReply, st.sampled_from(ERROR_CODES), st.text(min_size=1, max_size=200)),
    # safety: the e-stop and the agent's state
    st.builds(EstopCommand, st.booleans(), st.text(max_size=200)),
    st.builds(AgentState, st.from_regex(CHUNK_PATTERN, fullmatch=True), st.sampled_from(AGENT_PHASES), st.sampled_from(("realtime", "lockstep")),
              st.sampled_from(("simulated", "real")), st.integers(0, 10**6), st.text(max_size=200)),
)

json_scalars = st.none() | st.booleans() | st.integers() | finite | st.text(max_size=10)
json_values = st.recursive(
    json_scalars,
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=12,
)
MESSAGE_CLASSES = sorted(message_types().values(), key=lambda c: c.TYPE)


def typed_decode(cls: type[Message] | None, data) -> Message | None:
    """Decode; return None on PayloadError; let every other exception fail the test."""
    try:
        return decode(data) if cls is None else cls.from_json(data)
    except PayloadError:
        return None


# --------------------------------------------------------------------------- round trips


def test_every_message_type_is_generated():
    assert {c.TYPE for c in MESSAGE_CLASSES} == {
        "episode_request", "episode_result", "episode_done", "learner_state", "critic_point",
        "critic_reply", "kappa_command", "weights_command", "select_reply", "learner_episode",
        "error", "estop_command", "agent_state",
    }


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages)
def test_round_trip_is_exact(msg):
    data = msg.to_json()
    assert isinstance(data, bytes) and len(data) <= MAX_PAYLOAD_BYTES
    obj = json.loads(data)
    assert obj["v"] == 1 and obj["type"] == msg.TYPE
    again = type(msg).from_json(data)
    assert again == msg
    assert decode(data) == msg
    assert again.to_json() == data  # canonical encoding
    assert pickle.loads(pickle.dumps(msg)) == msg
    assert hash(again) == hash(msg)


@settings(deadline=None)
@given(critic_replies())
def test_nested_points_round_trip(reply):
    assert CriticPoint.from_json(reply.points[0].to_json()) == reply.points[0]


def test_examples_from_the_docs_decode():
    req = EpisodeRequest("ep-000042", "lifting", (0.3, 1.2, 1.6, 0.8, 0.6, 0.9, 1.1), 123456789)
    assert EpisodeRequest.from_json(req.to_json()).theta == req.theta
    res = EpisodeResult(
        "ep-000042", "bracing", "ok",
        {"damage": 0.0, "body_acc_sq": 31.7, "arm_power": 0.84}, total_cost=7.37,
        failures={"hardware_damage": False, "fallen": True},
        duration_s=2.0, wall_s=0.41, telemetry={"n_cycles": 400.0, "max_abs_pitch": 0.62},
        fault_counts={"emcy": 0}, detail="",
    )
    assert res.ok and res.failed("fallen") and not res.failed("over_current")
    assert TASKS["bracing"].total_cost(res.cost_terms) == pytest.approx(0.1 * 31.7 + 5 * 0.84)


DOC = Path(__file__).resolve().parents[2] / "docs" / "zenoh.md"


def test_every_json_example_in_the_docs_decodes_and_is_canonical():
    text = DOC.read_text()
    blocks = re.findall(r"```json\n(.*?)\n```", text, re.S)
    decoded = [decode(block.encode()) for block in blocks]
    assert {m.TYPE for m in decoded} == {c.TYPE for c in MESSAGE_CLASSES} - {"critic_point"}
    for block, msg in zip(blocks, decoded):
        assert json.loads(block) == json.loads(msg.to_json())
    selectors = re.findall(r"^ersac/ubot1/learner/(critic|select)\?(.*)$", text, re.M)
    assert len(selectors) == 3
    for key, params in selectors:
        cls = CriticQuery if key == "critic" else SelectQuery
        assert cls.from_parameters(params).to_parameters() == params


def test_numpy_inputs_are_normalised_to_plain_floats():
    req = EpisodeRequest("e1", "bracing", np.array([0.25]), np.int64(5))
    assert req.theta == (0.25,) and type(req.theta[0]) is float and type(req.seed) is int
    cmd = WeightsCommand({"damage": np.float32(2.0), "arm_power": 1})
    assert cmd.weights == {"damage": 2.0, "arm_power": 1.0}
    assert EpisodeRequest.from_json(req.to_json()) == req


# --------------------------------------------------------------------------- constructor validation


@pytest.mark.parametrize(
    ("build", "field"),
    [
        (lambda: EpisodeRequest("e1", "juggling", (0.5,), 1), "task"),
        (lambda: EpisodeRequest("e1", "bracing", (0.5, 0.5), 1), "theta"),
        (lambda: EpisodeRequest("e1", "bracing", (1.5,), 1), "theta[0]"),
        (lambda: EpisodeRequest("e1", "bracing", (math.nan,), 1), "theta[0]"),
        (lambda: EpisodeRequest("e1", "bracing", (0.5,), -1), "seed"),
        (lambda: EpisodeRequest("e1", "bracing", (0.5,), 2**32), "seed"),
        (lambda: EpisodeRequest("e1", "bracing", (0.5,), True), "seed"),
        (lambda: EpisodeRequest("e 1", "bracing", (0.5,), 1), "episode_id"),
        (lambda: EpisodeRequest("", "bracing", (0.5,), 1), "episode_id"),
        (lambda: EpisodeRequest("e1", "lifting", (0.0,) * 4 + (0.1, 1.0, 1.0), 1), "theta[4]"),
        (lambda: EpisodeResult("e1", "bracing", "ok", {"damage": 0.0}, 1.0), "cost_terms"),
        (lambda: EpisodeResult("e1", "bracing", "ok",
                               {"damage": 0, "body_acc_sq": 0, "arm_power": 0}, None), "total_cost"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, 1.0), "total_cost"),
        (lambda: EpisodeResult("e1", "bracing", "crashed", {}, None), "status"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {"power": 1.0}, None), "cost_terms.power"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None, failures={"fallen": 1}),
         "failures.fallen"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None, failures={"exploded": True}),
         "failures.exploded"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None, duration_s=-1.0), "duration_s"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None,
                               telemetry={"peak": math.inf}), "telemetry.peak"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None,
                               telemetry={"Peak Current": 1.0}), "telemetry"),
        (lambda: EpisodeResult("e1", "bracing", "aborted", {}, None, fault_counts={"emcy": -1}),
         "fault_counts.emcy"),
        (lambda: KappaCommand(10.5), "kappa"),
        (lambda: KappaCommand("1"), "kappa"),
        (lambda: WeightsCommand({}), "weights"),
        (lambda: WeightsCommand({"damage": -1.0}), "weights.damage"),
        (lambda: ErrorReply("oops", "x"), "code"),
        (lambda: ErrorReply("busy", ""), "reason"),
        (lambda: CriticPoint((0.5,), 1.0, -0.1, 1.0), "r"),
        (lambda: CriticReply("bracing", 1.0, (CriticPoint((0.5,), 1.0, 0.5, 1.0),)), "points[0].F"),
        (lambda: CriticReply("bracing", 1.0, (CriticPoint((2.0,), 1.0, 0.0, 1.0),)),
         "points[0].theta[0]"),
        (lambda: CriticReply("bracing", 1.0, ()), "points"),
        (lambda: SelectReply("bracing", (0.5,), 1.0, 1.0, 3.0, 1.0,
                             TASKS["bracing"].default_weights, False), "F"),
        (lambda: SelectReply("bracing", (0.5,), 1.0, 1.0, 2.0, 1.0, {"damage": 1.0}, False),
         "weights"),
        (lambda: LearnerState("run1", "bracing", "running", (0.5,), (0.0,), 0.0,
                              TASKS["bracing"].default_weights, 0), "sigma[0]"),
        (lambda: LearnerState("run1", "bracing", "running", (0.5,), (0.1, 0.1), 0.0,
                              TASKS["bracing"].default_weights, 0), "sigma"),
        (lambda: LearnerState("run1", "bracing", "dancing", (0.5,), (0.1,), 0.0,
                              TASKS["bracing"].default_weights, 0), "status"),
    ],
)
def test_invalid_values_raise_invalid_field_naming_the_field(build, field):
    with pytest.raises(InvalidField) as info:
        build()
    assert info.value.field == field, str(info.value)
    assert field in str(info.value)


def test_nested_objects_of_the_wrong_kind_name_their_field():
    done = json.loads(EpisodeDone("r1", 1.0, EpisodeRequest("e1", "bracing", (0.5,), 1),
                                  EpisodeResult("e1", "bracing", "aborted", {}, None)).to_json())
    done["request"] = [1, 2]
    with pytest.raises(InvalidField) as info:
        EpisodeDone.from_json(json.dumps(done).encode())
    assert info.value.field == "request" and "episode_request" in str(info.value)
    reply = json.loads(CriticReply("bracing", 0.0, (CriticPoint((0.5,), 1.0, 0.0, 1.0),)).to_json())
    reply["points"][0]["J"] = "1"
    with pytest.raises(InvalidField) as info:
        CriticReply.from_json(json.dumps(reply).encode())
    assert info.value.field == "points[0].J"


def test_episode_done_requires_matching_request_and_result():
    req = EpisodeRequest("e1", "bracing", (0.5,), 1)
    other = EpisodeResult("e2", "bracing", "aborted", {}, None)
    with pytest.raises(InvalidField, match="episode_id"):
        EpisodeDone("ubot1", 1.0, req, other)
    with pytest.raises(InvalidField, match="robot"):
        EpisodeDone("u/1", 1.0, req, EpisodeResult("e1", "bracing", "aborted", {}, None))


# --------------------------------------------------------------------------- garbage on the wire


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=200), st.sampled_from(MESSAGE_CLASSES + [None]))
def test_random_bytes_raise_typed_errors(data, cls):
    assert typed_decode(cls, data) is None


@settings(max_examples=300, deadline=None)
@given(json_values, st.sampled_from(MESSAGE_CLASSES + [None]))
def test_random_json_raises_typed_errors(value, cls):
    assert typed_decode(cls, json.dumps(value).encode()) is None


@settings(max_examples=300, deadline=None)
@given(st.dictionaries(st.text(max_size=12), json_values, max_size=8), st.sampled_from(MESSAGE_CLASSES))
def test_random_fields_under_a_valid_envelope_raise_typed_errors(fields, cls):
    obj = {**fields, "v": 1, "type": cls.TYPE}
    assert typed_decode(cls, json.dumps(obj).encode()) is None


def _paths(value, path=()):
    """Every (path, value) inside a JSON object, depth first."""
    yield path, value
    if isinstance(value, dict):
        for k, v in value.items():
            yield from _paths(v, (*path, k))
    elif isinstance(value, list):
        for i, v in enumerate(value):
            yield from _paths(v, (*path, i))


def _replace(obj, path, new):
    if not path:
        return new
    out = dict(obj) if isinstance(obj, dict) else list(obj)
    out[path[0]] = _replace(obj[path[0]], path[1:], new)
    return out


def _delete(obj, path):
    out = dict(obj) if isinstance(obj, dict) else list(obj)
    if len(path) == 1:
        del out[path[0]]
    else:
        out[path[0]] = _delete(obj[path[0]], path[1:])
    return out


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.data())
def test_mutated_values_are_typed_errors_or_still_valid(msg, data):
    obj = json.loads(msg.to_json())
    paths = [p for p, _ in _paths(obj) if p]
    path = data.draw(st.sampled_from(paths))
    new = data.draw(json_values)
    mutated = json.dumps(_replace(obj, path, new)).encode()
    out = typed_decode(type(msg), mutated)
    if out is not None:  # the replacement happened to be valid: then it must be faithful
        assert out.to_json() == type(msg).from_json(mutated).to_json()


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.data())
def test_deleted_fields_are_invalid_field(msg, data):
    obj = json.loads(msg.to_json())
    # deleting an entry of a mapping field (failures, telemetry...) may stay valid; deleting
    # a message field never does, except one a later revision added (it takes its default)
    top = data.draw(st.sampled_from(sorted(obj)))
    if top in type(msg).WIRE_OPTIONAL:
        again = type(msg).from_json(json.dumps(_delete(obj, (top,))).encode())
        assert getattr(again, top) == type(msg).__struct_defaults__[
            type(msg).__struct_fields__.index(top) - len(type(msg).__struct_fields__)]
        return
    with pytest.raises(InvalidField) as info:
        type(msg).from_json(json.dumps(_delete(obj, (top,))).encode())
    assert info.value.field == top


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, names.filter(lambda n: n not in ("v", "type")), json_values)
def test_extra_fields_are_invalid_field(msg, extra, value):
    obj = json.loads(msg.to_json())
    assume(extra not in obj)
    obj[extra] = value
    with pytest.raises(InvalidField) as info:
        type(msg).from_json(json.dumps(obj).encode())
    assert info.value.field == extra


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.data(), st.sampled_from(["NaN", "Infinity", "-Infinity"]))
def test_nan_and_infinity_literals_are_malformed(msg, data, literal):
    obj = json.loads(msg.to_json())
    numbers = [p for p, v in _paths(obj) if isinstance(v, float)]
    assume(numbers)
    path = data.draw(st.sampled_from(numbers))
    text = json.dumps(_replace(obj, path, "__X__")).replace('"__X__"', literal)
    with pytest.raises(MalformedPayload, match="non-finite"):
        type(msg).from_json(text.encode())


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(messages, st.data())
def test_overflowing_numbers_are_invalid_field(msg, data):
    obj = json.loads(msg.to_json())
    numbers = [p for p, v in _paths(obj) if isinstance(v, float)]
    assume(numbers)
    path = data.draw(st.sampled_from(numbers))
    text = json.dumps(_replace(obj, path, "__X__")).replace('"__X__"', "1e999")
    with pytest.raises(InvalidField, match="finite"):
        type(msg).from_json(text.encode())


@settings(deadline=None)
@given(messages, st.integers().filter(lambda v: v != 1))
def test_unknown_versions_are_unsupported(msg, version):
    obj = json.loads(msg.to_json())
    obj["v"] = version
    with pytest.raises(UnsupportedVersion) as info:
        type(msg).from_json(json.dumps(obj).encode())
    assert info.value.version == version
    with pytest.raises(UnsupportedVersion):
        decode(json.dumps(obj).encode())


@settings(deadline=None)
@given(messages, json_values.filter(lambda v: type(v) is not int))
def test_non_integer_versions_are_invalid_field(msg, version):
    obj = json.loads(msg.to_json())
    obj["v"] = version
    with pytest.raises(InvalidField) as info:
        type(msg).from_json(json.dumps(obj).encode())
    assert info.value.field == "v"


@settings(deadline=None)
@given(messages, st.sampled_from(MESSAGE_CLASSES))
def test_wrong_type_tag_is_invalid_field(msg, cls):
    assume(cls is not type(msg))
    with pytest.raises(InvalidField) as info:
        cls.from_json(msg.to_json())
    assert info.value.field == "type"


def test_envelope_and_framing_errors():
    good = KappaCommand(0.5).to_json()
    assert KappaCommand.from_json(bytearray(good)) == KappaCommand(0.5)
    assert KappaCommand.from_json(memoryview(good)) == KappaCommand(0.5)
    assert KappaCommand.from_json(good.decode()) == KappaCommand(0.5)
    for bad, kind in [
        (None, MalformedPayload),
        (12, MalformedPayload),
        ({"v": 1}, MalformedPayload),
        (b"", MalformedPayload),
        (b"\xff\xfe", MalformedPayload),
        (b'{"v":1,"type":"kappa_command","kappa":0.5,"kappa":0.6}', MalformedPayload),
        (b'{"v":1,"type":"kappa_command","kappa":0.5} trailing', MalformedPayload),
        (b'{"v":1,"type":"kappa_command","kappa":' + b"1" * 5000 + b"}", MalformedPayload),
        (b'{"v":1,"type":"kappa_command","kappa":' + b"[" * 100_000 + b"}", MalformedPayload),
        (b'{"v":1,"type":"kappa_command","kappa":[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[[['
         b"]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]]}", MalformedPayload),
        (b'{"type":"kappa_command","kappa":0.5}', InvalidField),
        (b'{"v":true,"type":"kappa_command","kappa":0.5}', InvalidField),
        (b'{"v":1.0,"type":"kappa_command","kappa":0.5}', InvalidField),
        (b'{"v":1,"kappa":0.5}', InvalidField),
        (b'{"v":1,"type":"kappa_command","kappa":true}', InvalidField),
        (b'{"v":1,"type":"kappa_command","kappa":"0.5"}', InvalidField),
    ]:
        with pytest.raises(kind):
            KappaCommand.from_json(bad)
    with pytest.raises(InvalidField, match="type"):
        decode(b'{"v":1,"type":"no_such_message"}')


def test_size_cap_applies_to_decode_and_encode():
    big = b'{"v":1,"type":"error","code":"busy","reason":"' + b"x" * MAX_PAYLOAD_BYTES + b'"}'
    with pytest.raises(PayloadTooLarge):
        ErrorReply.from_json(big)
    with pytest.raises(PayloadTooLarge):
        ErrorReply.from_json(b" " * (MAX_PAYLOAD_BYTES + 1))
    with pytest.raises(PayloadTooLarge):
        codec.dumps({"x": "y" * MAX_PAYLOAD_BYTES})


def test_the_largest_legal_critic_reply_fits_the_cap():
    # longest float reprs that stay inside the lifting bounds, and J, r, F near 1e300
    theta = (-1.2345678901234567e-05, 1.2345678901234567e-05) * 2 + (0.20000000000000004,) * 3
    kappa = -9.876543210987654
    j, r = -1.2345678901234567e300, 1.2345678901234567e300
    point = CriticPoint(theta, j, r, j + kappa * r)
    reply = CriticReply("lifting", kappa, (point,) * MAX_CRITIC_POINTS)
    assert len(reply.to_json()) < MAX_PAYLOAD_BYTES
    assert 3 ** TASKS["lifting"].dim <= MAX_CRITIC_POINTS  # a 3-point grid of lifting is legal


# --------------------------------------------------------------------------- selector parameters


@st.composite
def critic_queries(draw):
    kappa = draw(st.none() | kappas)
    if draw(st.booleans()):
        return CriticQuery(grid=draw(st.integers(2, GRID_MAX)), kappa=kappa)
    dim = draw(st.integers(1, 7))
    pts = draw(st.lists(st.tuples(*[finite] * dim), min_size=1, max_size=5))
    return CriticQuery(tuple(pts), None, kappa)


select_queries = st.builds(
    SelectQuery,
    kappas,
    st.none() | st.dictionaries(names, nonneg, min_size=1, max_size=6),
    st.booleans(),
)


@settings(deadline=None)
@given(critic_queries())
def test_critic_query_parameters_round_trip(query):
    text = query.to_parameters()
    assert "?" not in text and "#" not in text
    assert CriticQuery.from_parameters(text) == query


@settings(deadline=None)
@given(select_queries)
def test_select_query_parameters_round_trip(query):
    assert SelectQuery.from_parameters(query.to_parameters()) == query


@settings(max_examples=300, deadline=None)
@given(st.text(max_size=60), st.sampled_from([CriticQuery, SelectQuery]))
def test_random_parameter_text_raises_typed_errors(text, cls):
    try:
        cls.from_parameters(text)
    except PayloadError:
        pass


@pytest.mark.parametrize(
    ("cls", "text", "field"),
    [
        (CriticQuery, "", "theta"),
        (CriticQuery, "theta=0.1;grid=3", "theta"),
        (CriticQuery, "theta=nan", "theta[0][0]"),
        (CriticQuery, "theta=inf", "theta[0][0]"),
        (CriticQuery, "theta=1e999", "theta[0][0]"),
        (CriticQuery, "theta=0.1,", "theta[0][1]"),
        (CriticQuery, "theta=0.1|0.2,0.3", "theta"),
        (CriticQuery, "theta= 0.1", "theta[0][0]"),
        (CriticQuery, "theta=1_0", "theta[0][0]"),
        (CriticQuery, "grid=1", "grid"),
        (CriticQuery, "grid=-3", "grid"),
        (CriticQuery, "grid=3.0", "grid"),
        (CriticQuery, "grid=3;grid=4", "grid"),
        (CriticQuery, "grid=3;kappa=11", "kappa"),
        (CriticQuery, "grid=3;colour=red", "colour"),
        (SelectQuery, "", "kappa"),
        (SelectQuery, "kappa=x", "kappa"),
        (SelectQuery, "kappa=1;adopt=yes", "adopt"),
        (SelectQuery, "kappa=1;weights=damage", "weights"),
        (SelectQuery, "kappa=1;weights=damage:-1", "weights.damage"),
        (SelectQuery, "kappa=1;weights=damage:1,damage:2", "weights.damage"),
        (SelectQuery, "kappa=1;weights=Bad Name:1", "weights"),
        (SelectQuery, "kappa=1;weights=", "weights"),
    ],
)
def test_bad_parameters_name_the_field(cls, text, field):
    with pytest.raises(InvalidField) as info:
        cls.from_parameters(text)
    assert info.value.field == field, str(info.value)


def test_parameters_accept_mappings_and_skip_zenoh_reserved_keys():
    assert SelectQuery.from_parameters({"kappa": "0.5", "adopt": "true"}) == SelectQuery(0.5, None, True)
    assert SelectQuery.from_parameters("kappa=0.5;_time=[now(-1h)..];_anyke") == SelectQuery(0.5)
    assert SelectQuery.from_parameters("kappa=-2;adopt").adopt is True


def test_critic_query_points_for_a_task():
    q = CriticQuery.from_parameters("grid=5")
    assert q.points_for("bracing") == ((0.0,), (0.25,), (0.5,), (0.75,), (1.0,))
    grid = CriticQuery(grid=3).points_for("lifting")
    spec = TASKS["lifting"]
    assert len(grid) == 3**7 and grid[0] == spec.lower and grid[-1] == spec.upper
    with pytest.raises(InvalidField, match="exceed"):
        CriticQuery(grid=4).points_for("lifting")
    with pytest.raises(InvalidField, match="theta"):
        CriticQuery(((0.5, 0.5),)).points_for("bracing")
    with pytest.raises(InvalidField) as info:
        CriticQuery(((0.5,), (1.5,))).points_for("bracing")
    assert info.value.field == "theta[1][0]"


# --------------------------------------------------------------------------- tasks


def test_task_specs_match_the_design():
    bracing, lifting = TASKS["bracing"], TASKS["lifting"]
    assert bracing.dim == 1 and bracing.lower == (0.0,) and bracing.upper == (1.0,)
    assert dict(bracing.default_weights) == {"damage": 10.0, "body_acc_sq": 0.1, "arm_power": 5.0}
    assert bracing.horizon_s == 2.0 and lifting.horizon_s == 6.0
    assert lifting.dim == 7
    assert [lifting.default_weights[n] for n in lifting.term_names] == [
        0.001, 0.001, 0.5, 0.5, 0.05, 0.01,
    ]
    assert sum(lifting.upper[4:]) <= lifting.horizon_s  # the spline fits in the episode
    # damage is an additive penalty: an undamaged, motionless trial costs 0, a damaged one 10
    zero = {n: 0.0 for n in bracing.term_names}
    assert bracing.total_cost(zero) == 0.0
    assert bracing.total_cost({**zero, "damage": 1.0}) == 10.0
    assert bracing.total_cost({**zero, "damage": 1.0}, {"damage": 0.0}) == 0.0


@settings(deadline=None)
@given(task_names, st.data())
def test_total_cost_is_linear_in_the_terms(task, data):
    spec = TASKS[task]
    terms = data.draw(st.fixed_dictionaries({n: moderate for n in spec.term_names}))
    w = data.draw(weights(task))
    expected = math.fsum(w[n] * terms[n] for n in spec.term_names)
    assert spec.total_cost(terms, w) == pytest.approx(expected, rel=1e-12, abs=1e-9)


@settings(deadline=None)
@given(task_names, st.data())
def test_weighted_total_sums_in_one_fixed_order(task, data):
    """The total is the products added one by one in the sorted order of the names, whatever
    order the mappings come in: the same bits for one episode's terms and for numpy columns of
    many episodes' terms (how the learner re-costs its stored episodes)."""
    spec = TASKS[task]
    rows = data.draw(st.lists(st.fixed_dictionaries({n: moderate for n in spec.term_names}),
                              min_size=1, max_size=8))
    w = data.draw(weights(task))
    for terms in rows:
        expected = 0.0
        for name in sorted(spec.term_names):
            expected += w[name] * terms[name]
        assert spec.total_cost(terms, w) == expected
        assert spec.total_cost(dict(reversed(list(terms.items()))), dict(reversed(list(w.items())))) == expected
    columns = {n: np.array([t[n] for t in rows]) for n in reversed(spec.term_names)}
    assert weighted_total(columns, w).tolist() == [spec.total_cost(t, w) for t in rows]
