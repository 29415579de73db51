"""decode_reply on real replies from a real queryable (through the module's embedded router)."""
from __future__ import annotations

import pytest

from ersac_hil.daemon.replies import MalformedReply, ReplyRefused, ReplyTimeout, decode_reply
from helpers.waiting import wait_for_match
from protocol.zenoh import ErrorReply, KappaCommand

KEY = "ersac/replies/test"
QUERYABLE: dict[str, str] = {}
"""The zid of the queryable's session (the ``replier`` fixture's)."""


@pytest.fixture(scope="module")
def replier(router):
    """A queryable answering by the selector's ``kind`` parameter; ``hold`` never answers."""
    server, client = router.open_client(), router.open_client()
    held: list = []

    def on_query(query) -> None:  # noqa: ANN001
        kind = str(query.parameters)
        if kind == "kind=hold":
            held.append(query)  # answered never; dropped at teardown
            return
        with query:
            if kind == "kind=ok":
                query.reply(KEY, KappaCommand(1.5).to_json())
            elif kind == "kind=garbage":
                query.reply(KEY, b"{not json")
            elif kind == "kind=refused":
                query.reply_err(ErrorReply("busy", "try later").to_json())
            else:
                query.reply_err(b"something broke")

    queryable = server.declare_queryable(KEY, on_query)
    QUERYABLE["zid"] = str(server.info.zid())
    querier = client.declare_querier(KEY)
    assert wait_for_match(querier)
    yield client
    for q in held:
        q.drop()
    querier.undeclare()
    queryable.undeclare()
    client.close()
    server.close()


def _reply(session, kind: str, timeout: float = 10.0):  # noqa: ANN001
    replies = list(session.get(f"{KEY}?kind={kind}", timeout=timeout))
    assert len(replies) == 1
    return replies[0]


def test_an_ok_reply_decodes_into_the_message(replier):
    assert decode_reply(_reply(replier, "ok"), KappaCommand) == KappaCommand(1.5)


def test_an_ok_reply_with_an_invalid_payload_is_malformed(replier):
    with pytest.raises(MalformedReply, match="invalid kappa_command"):
        decode_reply(_reply(replier, "garbage"), KappaCommand)


def test_an_error_reply_is_a_refusal_with_its_code(replier):
    with pytest.raises(ReplyRefused) as info:
        decode_reply(_reply(replier, "refused"), KappaCommand)
    assert info.value.error == ErrorReply("busy", "try later")


def test_an_error_reply_without_an_error_reply_payload_is_malformed(replier):
    with pytest.raises(MalformedReply, match="something broke"):
        decode_reply(_reply(replier, "text"), KappaCommand)


def test_zenohs_own_timeout_is_a_timeout(replier):
    # The session's own timer and the router's (which the query's timeout reaches) may both
    # end the held query: one "Timeout" error or two (seen in CI under load), never an answer.
    # The session's own carries no replier id, the router's its id (seen beside CPU hogs).
    replies = list(replier.get(f"{KEY}?kind=hold", timeout=0.3))
    assert 1 <= len(replies) <= 2
    for reply in replies:
        assert reply.replier_id is None or str(reply.replier_id.zid) != QUERYABLE["zid"]  # Zenoh's, not the queryable's
        with pytest.raises(ReplyTimeout):
            decode_reply(reply, KappaCommand)
