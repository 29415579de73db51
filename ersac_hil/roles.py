"""Roles and the Zenoh access-control rules that enforce them (pure data, no I/O).

A deployment has one Zenoh router and clients; every link is TLS with a client certificate
(mTLS) whose common name is the role. The router's access control (Zenoh 1.10
``access_control``, default deny) allows each role exactly what it needs, keyed on the
certificate's common name:

=========  ===================================================================================
role       may
=========  ===================================================================================
router     listen (its certificate is the TLS server's); no rules of its own
daemon     query ``episode/run``; see the agent's liveliness tokens; serve ``learner/state``,
           ``learner/critic``, ``learner/select``, ``learner/episodes`` (history); receive
           ``learner/kappa`` and ``learner/weights`` puts; publish ``learner/episodes`` and
           ``learner/error``
agent      serve ``episode/run`` (declare the queryable, reply); declare ``agent/alive`` and
           ``agent/session/<zid>``;
           publish ``episode/done``; receive ``agent/go``
operator   put ``learner/kappa``, ``learner/weights``, ``agent/go``; query ``learner/state``,
           ``learner/critic``, ``learner/select`` (also with ``adopt=true``),
           ``learner/episodes``; read
           ``learner/episodes``, ``learner/error``, ``episode/done``, ``agent/alive``
observer   query ``learner/state``, ``learner/critic`` and ``learner/episodes``; read
           ``learner/episodes``, ``learner/error``, ``episode/done``, ``agent/alive``; nothing else
simulator  the CAN bus only: send and receive frames on ``can/**`` (the CAN-over-Zenoh
           channels, ``ersac_hil.canbus.zenoh_bus``), like the agent; nothing else
=========  ===================================================================================

The CAN bus between an agent and its robot (CAN over Zenoh) is the one key space outside
``<prefix>/<robot>/``: ``can/<channel>``, sent and received by ``agent`` and ``simulator``
(a simulated robot, or a gateway to a real one), by no other role.

Everything else is denied: a denied put is dropped, a denied query gets no reply, a denied
queryable or liveliness token is declared locally but nothing is ever routed to it. So only
the agent's identity can answer ``episode/run`` and only an operator can steer the learner.
Rules are written per direction as the router sees a client's link: ``ingress`` is what
the client sends, ``egress`` what the router delivers to it.
"""
from __future__ import annotations

from typing import Any

__all__ = ["ROLES", "CLIENT_ROLES", "PERMISSIONS", "CAN_KEYS", "CAN_ROLES", "access_control"]

#: Every role; the certificate common name of a role is its name.
ROLES: tuple[str, ...] = ("router", "daemon", "agent", "operator", "observer", "simulator")
#: Roles that connect to the router as Zenoh clients.
CLIENT_ROLES: tuple[str, ...] = ROLES[1:]

_RUN, _ALIVE, _DONE, _GO = "episode/run", "agent/alive", "episode/done", "agent/go"
_SESSION = "agent/session/*"
_STATE, _CRITIC, _SELECT = "learner/state", "learner/critic", "learner/select"
_KAPPA, _WEIGHTS = "learner/kappa", "learner/weights"
_EPISODES, _ERROR = "learner/episodes", "learner/error"
_READ = (_EPISODES, _ERROR, _DONE)
_LIVELINESS_READ = ("declare_liveliness_subscriber", "liveliness_query")

#: role -> flow -> [(message kinds, key suffixes under <prefix>/<robot>/)].
PERMISSIONS: dict[str, dict[str, list[tuple[tuple[str, ...], tuple[str, ...]]]]] = {
    "router": {"ingress": [], "egress": []},
    "simulator": {"ingress": [], "egress": []},
    "daemon": {
        "ingress": [
            (("query",), (_RUN,)),
            (_LIVELINESS_READ, (_ALIVE, _SESSION)),
            (("declare_queryable", "reply"), (_STATE, _CRITIC, _SELECT, _EPISODES)),
            (("declare_subscriber",), (_KAPPA, _WEIGHTS)),
            (("put",), (_EPISODES, _ERROR)),
        ],
        "egress": [
            (("declare_queryable", "reply"), (_RUN,)),
            (("liveliness_token", "reply"), (_ALIVE, _SESSION)),
            (("query",), (_STATE, _CRITIC, _SELECT, _EPISODES)),
            (("put",), (_KAPPA, _WEIGHTS)),
            (("declare_subscriber",), (_EPISODES, _ERROR)),
        ],
    },
    "agent": {
        "ingress": [
            (("declare_queryable", "reply"), (_RUN,)),
            (("liveliness_token",), (_ALIVE, _SESSION)),
            (("put",), (_DONE,)),
            (("declare_subscriber",), (_GO,)),
        ],
        "egress": [
            (("query",), (_RUN,)),
            (("declare_subscriber",), (_DONE,)),
            (("put",), (_GO,)),
        ],
    },
    "operator": {
        "ingress": [
            (("put",), (_KAPPA, _WEIGHTS, _GO)),
            (("query",), (_STATE, _CRITIC, _SELECT, _EPISODES)),
            (("declare_subscriber",), _READ),
            (_LIVELINESS_READ, (_ALIVE,)),
        ],
        "egress": [
            (("declare_queryable", "reply"), (_STATE, _CRITIC, _SELECT, _EPISODES)),
            (("declare_subscriber",), (_KAPPA, _WEIGHTS, _GO)),
            (("put",), _READ),
            (("liveliness_token", "reply"), (_ALIVE,)),
        ],
    },
    "observer": {
        "ingress": [
            (("query",), (_STATE, _CRITIC, _EPISODES)),
            (("declare_subscriber",), _READ),
            (_LIVELINESS_READ, (_ALIVE,)),
        ],
        "egress": [
            (("declare_queryable", "reply"), (_STATE, _CRITIC, _EPISODES)),
            (("put",), _READ),
            (("liveliness_token", "reply"), (_ALIVE,)),
        ],
    },
}


#: The CAN-over-Zenoh channels (``ersac_hil.canbus.zenoh_bus``: key ``can/<channel>``).
CAN_KEYS: tuple[str, ...] = ("can/**",)
#: Roles on the CAN bus: each sends frames and receives the others' (both directions).
CAN_ROLES: tuple[str, ...] = ("agent", "simulator")
_CAN_MESSAGES = ("put", "declare_subscriber")


def access_control(prefix: str = "ersac", robot: str = "*") -> dict[str, Any]:
    """The router's ``access_control`` section (Zenoh 1.10 schema) for the roles above.

    Args:
        prefix: the key prefix (one or more chunks).
        robot: one robot's key chunk, or ``*`` for every robot under ``prefix``.
    """
    rules, policies = [], []
    for role, flows in PERMISSIONS.items():
        ids = []
        for flow, grants in flows.items():
            for i, (messages, suffixes) in enumerate(grants):
                rule_id = f"{role}-{flow}-{i}"
                rules.append({
                    "id": rule_id, "permission": "allow", "flows": [flow],
                    "messages": list(messages),
                    "key_exprs": [f"{prefix}/{robot}/{suffix}" for suffix in suffixes],
                })
                ids.append(rule_id)
        if role in CAN_ROLES:
            rules.append({"id": f"{role}-can", "permission": "allow", "flows": ["ingress", "egress"],
                          "messages": list(_CAN_MESSAGES), "key_exprs": list(CAN_KEYS)})
            ids.append(f"{role}-can")
        if ids:
            policies.append({"id": f"{role}-policy", "rules": ids, "subjects": [role]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": role, "cert_common_names": [role]} for role in ROLES],
        "policies": policies,
    }
