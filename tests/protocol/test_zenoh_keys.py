"""Key-space builders: exact key strings, validation, and agreement with Zenoh's own parser."""
from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import pytest
import zenoh
from hypothesis import given
from hypothesis import strategies as st

from protocol.zenoh import CHUNK_PATTERN, KeySpace, KeySpaceError

chunks = st.from_regex(CHUNK_PATTERN, fullmatch=True)
prefixes = st.lists(chunks, min_size=1, max_size=3).map("/".join)

DOC = Path(__file__).resolve().parents[2] / "docs" / "zenoh.md"
KEY_ROW = re.compile(r"^\|\s*`(\w+)`\s*\|\s*`ersac/ubot1/([\w/]+)`\s*\|")


def documented_keys() -> dict[str, str]:
    """The key table of docs/zenoh.md: attribute name -> key of robot ``ubot1``."""
    rows = (KEY_ROW.match(line) for line in DOC.read_text().splitlines())
    return {m.group(1): f"ersac/ubot1/{m.group(2)}" for m in rows if m}


def test_every_key_is_the_documented_one():
    ks = KeySpace("ubot1")
    assert ks.root == "ersac/ubot1"
    assert ks.keys() == documented_keys()
    for name, key in ks.keys().items():
        assert getattr(ks, name) == key


def test_custom_prefix_with_several_chunks():
    ks = KeySpace("r2", prefix="lab/ersac")
    assert ks.episode_run == "lab/ersac/r2/episode/run"
    assert ks.learner_all == "lab/ersac/r2/learner/**"


def test_keyspace_is_frozen():
    ks = KeySpace("r1")
    with pytest.raises(dataclasses.FrozenInstanceError):
        ks.robot = "r2"  # type: ignore[misc]


@given(robot=chunks, prefix=prefixes)
def test_every_key_is_a_canonical_zenoh_key(robot, prefix):
    ks = KeySpace(robot, prefix)
    for key in ks.keys().values():
        assert str(zenoh.KeyExpr(key)) == key
        assert not key.startswith("/") and not key.endswith("/") and "//" not in key
        assert zenoh.KeyExpr(ks.learner_all).includes(key) == ("/learner/" in key[len(ks.root):])
        assert KeySpace.from_key(key, prefix) == ks
    assert zenoh.KeyExpr(KeySpace.alive_pattern(prefix)).includes(ks.agent_alive)
    assert not zenoh.KeyExpr(KeySpace.alive_pattern(prefix)).includes(ks.episode_run)


@pytest.mark.parametrize(
    "robot",
    ["", "a/b", "/a", "a/", "*", "**", "$*", "a*", "a?b", "a#b", " a", "a b", "a\t", "\n",
     "-a", ".", "..", "é", "a" * 65, None, 3, b"r1"],
)
def test_invalid_robot_names_raise_keyspace_error(robot):
    with pytest.raises(KeySpaceError):
        KeySpace(robot)  # type: ignore[arg-type]


@pytest.mark.parametrize("prefix", ["", "/ersac", "ersac/", "ersac//x", "ersac/*", "e?x", "a#b", 1])
def test_invalid_prefixes_raise_keyspace_error(prefix):
    with pytest.raises(KeySpaceError):
        KeySpace("r1", prefix)  # type: ignore[arg-type]


@given(st.text(max_size=20))
def test_arbitrary_robot_text_is_either_a_valid_chunk_or_refused(text):
    try:
        ks = KeySpace(text)
    except KeySpaceError:
        assert CHUNK_PATTERN.fullmatch(text) is None
    else:
        assert "/" not in text and str(zenoh.KeyExpr(ks.episode_run)) == ks.episode_run


def test_selector_puts_parameters_after_question_mark():
    ks = KeySpace("r1")
    assert ks.selector(ks.learner_critic) == "ersac/r1/learner/critic"
    assert ks.selector(ks.learner_critic, "") == "ersac/r1/learner/critic"
    assert ks.selector(ks.learner_critic, "theta=0.4") == "ersac/r1/learner/critic?theta=0.4"
    assert ks.selector(ks.learner_select, {"kappa": "1.0", "adopt": "true"}) == (
        "ersac/r1/learner/select?kappa=1.0;adopt=true"
    )
    with pytest.raises(KeySpaceError):
        ks.selector(ks.learner_critic + "?grid=3", "theta=0.4")


@pytest.mark.parametrize(
    "key",
    ["ersac/r1", "ersac/r1/episode", "ersac/r1/episode/run/x", "other/r1/episode/run",
     "ersac/*/episode/run", "ersac//episode/run", 5],
)
def test_from_key_refuses_foreign_keys(key):
    with pytest.raises(KeySpaceError):
        KeySpace.from_key(key)  # type: ignore[arg-type]
