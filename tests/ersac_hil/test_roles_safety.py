"""The e-stop and the agent's state in the access-control rules: only an operator may put
``agent/estop`` (an observer's put is dropped by the router), only the agent receives it and
serves ``agent/state``, and every reading role may ask it."""
from __future__ import annotations

from ersac_hil.roles import ROLES, access_control


def allowed(role: str, flow: str, message: str, suffix: str) -> bool:
    acl = access_control()
    rules = {r["id"]: r for r in acl["rules"]}
    policies = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in acl["policies"]}
    return any(flow in r["flows"] and message in r["messages"] and f"ersac/*/{suffix}" in r["key_exprs"]
               for r in policies.get(role, []))


def test_only_an_operator_puts_the_estop_and_only_the_agent_hears_it():
    assert [r for r in ROLES if allowed(r, "ingress", "put", "agent/estop")] == ["operator"]
    assert [r for r in ROLES if allowed(r, "egress", "put", "agent/estop")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "declare_subscriber", "agent/estop")] == ["agent"]


def test_only_the_agent_serves_its_state_and_readers_ask_it():
    assert [r for r in ROLES if allowed(r, "ingress", "declare_queryable", "agent/state")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "reply", "agent/state")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "query", "agent/state")] == ["daemon", "operator", "observer"]
