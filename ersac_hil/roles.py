"""Roles and the Zenoh access-control rules that enforce them (pure data, no I/O).

A deployment has one Zenoh router and clients; every link is TLS with a client certificate
(mTLS) whose common name is the role. The router's access control (Zenoh 1.10
``access_control``, default deny) allows each role exactly what it needs, keyed on the
certificate's common name:

=========  ===================================================================================
role       may
=========  ===================================================================================
router     listen (its certificate is the TLS server's); no rules of its own
daemon     query ``episode/run`` and ``agent/state``; see the agent's liveliness tokens; serve ``learner/state``,
           ``learner/critic``, ``learner/select``, ``learner/episodes`` (history); receive
           ``learner/kappa`` and ``learner/weights`` puts; publish ``learner/episodes`` and
           ``learner/error``
agent      serve ``episode/run`` (declare the queryable, reply); declare ``agent/alive`` and
           ``agent/session/<zid>``;
           publish ``episode/done``; receive ``agent/go`` and ``agent/estop``; serve
           ``agent/state``
operator   put ``learner/kappa``, ``learner/weights``, ``agent/go``, ``agent/estop``; query
           ``agent/state``, ``learner/state``,
           ``learner/critic``, ``learner/select`` (also with ``adopt=true``),
           ``learner/episodes``; read
           ``learner/episodes``, ``learner/error``, ``episode/done``, ``agent/alive``
observer   query ``learner/state``, ``learner/critic``, ``learner/episodes`` and
           ``agent/state``; read
           ``learner/episodes``, ``learner/error``, ``episode/done``, ``agent/alive``; nothing else
simulator  the CAN bus only: send and receive frames on ``can/**`` (the CAN-over-Zenoh
           channels, ``ersac_hil.canbus.zenoh_bus``), like the agent; nothing else
=========  ===================================================================================

ROS 2 (``agent --ros2``, ``ersac_hil.ros2``) lives outside ``<prefix>/`` too: on its ROS domain
the agent may put ``<domain>/**`` and declare tokens ``@ros2_lv/<domain>/**`` and is told of
the subscribers there; operators and observers may subscribe to and read them (:func:`ros2_rules`).

The CAN bus between an agent and its robot (CAN over Zenoh) is the other key space outside
``<prefix>/<robot>/``: ``can/<channel>``, sent and received by ``agent`` and ``simulator``
(a simulated robot, or a gateway to a real one), by no other role.

Per-robot identities (``certs init --robot ubot1 --robot ubot2``): instead of the fleet-wide
``agent`` and ``simulator``, each robot gets ``agent-<robot>`` and ``simulator-<robot>``, with
the same rules limited to that robot: ``<prefix>/<robot>/...`` and its CAN channel
``can/<robot>``. A robot's certificate then cannot serve another robot's episodes, declare its
tokens, or send or hear frames on its bus (a robot of a fleet that is lost or compromised
speaks only for itself).

Everything else is denied: a denied put is dropped, a denied query gets no reply, a denied
queryable or liveliness token is declared locally but nothing is ever routed to it. So only
the agent's identity can answer ``episode/run`` and only an operator can steer the learner.
Rules are per direction as the router sees a client's link: ``ingress`` is what the client
sends, ``egress`` what the router delivers to it. Only the ingress is written down; each
role's egress is derived from it (``_TOLD``: a querier is told of queryables and replies, a
publisher of subscribers, a subscriber gets puts, a queryable gets queries, a liveliness reader
gets tokens), so granting a role something to send cannot forget what it must hear back.
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from protocol.zenoh.keys import DEFAULT_PREFIX

__all__ = ["ROLES", "CLIENT_ROLES", "PERMISSIONS", "CAN_KEYS", "CAN_ROLES", "ROBOT_ROLES", "ROS2_PUBLISHERS",
           "ROS2_READERS", "ros2_rules", "identities",
           "parse_identity", "access_control", "permitted"]

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

#: What the router delivers to a client because of what the client sends (Zenoh 1.10 access
#: control filters both directions): a querier is told of queryables and gets their replies; a
#: publisher is told of subscribers (without it, write-side filtering drops its samples); a
#: subscriber gets the puts; a queryable gets the queries; a liveliness reader gets the tokens
#: and the replies to its liveliness queries. A liveliness token needs nothing back.
_TOLD: dict[str, tuple[str, ...]] = {
    "query": ("declare_queryable", "reply"),
    "put": ("declare_subscriber",),
    "declare_subscriber": ("put",),
    "declare_queryable": ("query",),
    "declare_liveliness_subscriber": ("liveliness_token", "reply"),
    "liveliness_query": ("liveliness_token", "reply"),
}


def _told(messages: Sequence[str]) -> tuple[str, ...]:
    """The message kinds the router must deliver to a client that sends ``messages``."""
    told: list[str] = []
    for message in messages:
        told += [m for m in _TOLD.get(message, ()) if m not in told]
    return tuple(told)


def _with_egress(ingress: list[tuple[tuple[str, ...], tuple[str, ...]]]) -> dict[str, list]:
    """``{"ingress": ingress, "egress": ...}``: each grant's egress derived by :func:`_told`."""
    return {"ingress": ingress,
            "egress": [(told, keys) for messages, keys in ingress if (told := _told(messages))]}


#: role -> flow -> [(message kinds, key suffixes under <prefix>/<robot>/)]. Only what a role may
#: send is written down (``ingress``); what it is told of (``egress``) follows from it.
_SENDS: dict[str, list[tuple[tuple[str, ...], tuple[str, ...]]]] = {
    "router": [],
    "simulator": [],
    "daemon": [
        (("query",), (_RUN,)),
        (_LIVELINESS_READ, (_ALIVE, _SESSION)),
        (("declare_queryable", "reply"), (_STATE, _CRITIC, _SELECT, _EPISODES)),
        (("declare_subscriber",), (_KAPPA, _WEIGHTS)),
        (("put",), (_EPISODES, _ERROR)),
    ],
    "agent": [
        (("declare_queryable", "reply"), (_RUN,)),
        (("liveliness_token",), (_ALIVE, _SESSION)),
        (("put",), (_DONE,)),
        (("declare_subscriber",), (_GO,)),
    ],
    "operator": [
        (("put",), (_KAPPA, _WEIGHTS, _GO)),
        (("query",), (_STATE, _CRITIC, _SELECT, _EPISODES)),
        (("declare_subscriber",), _READ),
        (_LIVELINESS_READ, (_ALIVE,)),
    ],
    "observer": [
        (("query",), (_STATE, _CRITIC, _EPISODES)),
        (("declare_subscriber",), _READ),
        (_LIVELINESS_READ, (_ALIVE,)),
    ],
}

# -- safety: the e-stop (an operator's put only) and the agent's state (anyone who reads) ----
_ESTOP, _AGENT_STATE = "agent/estop", "agent/state"
_SENDS["agent"] += [(("declare_subscriber",), (_ESTOP,)), (("declare_queryable", "reply"), (_AGENT_STATE,))]
_SENDS["operator"].append((("put",), (_ESTOP,)))
for _role in ("daemon", "operator", "observer"):
    _SENDS[_role].append((("query",), (_AGENT_STATE,)))

PERMISSIONS: dict[str, dict[str, list[tuple[tuple[str, ...], tuple[str, ...]]]]] = {
    role: _with_egress(grants) for role, grants in _SENDS.items()}


# ROS 2 over rmw_zenoh (``ersac_hil.ros2``, ``agent --ros2``): outside ``<prefix>/<robot>/``,
# the data keys ``<domain>/**`` and the liveliness tokens ``@ros2_lv/<domain>/**`` of one ROS
# domain. The agent publishes and declares its node's tokens; operators and observers (and a
# ROS 2 machine given an observer's certificate) subscribe and read the tokens.
#: Roles that publish for ROS 2, and roles that may read it.
ROS2_PUBLISHERS: tuple[str, ...] = ("agent",)
ROS2_READERS: tuple[str, ...] = ("operator", "observer")


def ros2_rules(name: str, role: str, domain: int = 0, robot: str | None = None) -> list[dict[str, Any]]:
    """The access-control rules of identity ``name`` (of ``role``) on ROS domain ``domain``.

    A robot's own agent identity (``robot`` given) publishes only under its robot's default
    namespace ``/<robot>`` (``agent --ros2`` without ``--ros-namespace``): data keys
    ``<domain>/<robot>/**`` and the tokens whose namespace field is ``%<robot>``, so one robot's
    agent cannot speak for another's topics."""
    data, tokens = [f"{domain}/**"], [f"@ros2_lv/{domain}/**"]
    if role in ROS2_PUBLISHERS and robot is not None:
        from ersac_hil.ros2.names import mangle, robot_namespace  # pure: re and struct only
        namespace = robot_namespace(robot)
        # @ros2_lv/<domain>/<zid>/<nid>/<eid>/<kind>/<enclave>/<namespace>/...
        data, tokens = [f"{domain}{namespace}/**"], [f"@ros2_lv/{domain}/*/*/*/*/*/{mangle(namespace)}/**"]
    if role in ROS2_PUBLISHERS:
        sends = [(("put",), data), (("liveliness_token",), tokens)]
    elif role in ROS2_READERS:
        sends = [(("declare_subscriber",), data), (_LIVELINESS_READ, tokens)]
    else:
        return []
    grants = [("ingress", messages, keys) for messages, keys in sends]
    for messages, keys in sends:
        if told := _told(messages):
            # a publisher is told of the readers' subscribers anywhere on the domain: a reader's
            # ``<domain>/**`` is no subset of ``<domain>/<robot>/**``
            grants.append(("egress", told, [f"{domain}/**"] if "put" in messages else keys))
    return [{"id": f"{name}-ros2-{i}", "permission": "allow", "flows": [flow], "messages": list(messages),
             "key_exprs": keys} for i, (flow, messages, keys) in enumerate(grants)]


#: The CAN-over-Zenoh channels (``ersac_hil.canbus.zenoh_bus``: key ``can/<channel>``).
CAN_KEYS: tuple[str, ...] = ("can/**",)
#: Roles on the CAN bus: each sends frames and receives the others' (both directions).
CAN_ROLES: tuple[str, ...] = ("agent", "simulator")
_CAN_MESSAGES = ("put", "declare_subscriber")


#: Roles issued per robot when a deployment names its robots (the robot side of the system).
ROBOT_ROLES: tuple[str, ...] = ("agent", "simulator")


def identities(robots: Sequence[str] = ()) -> list[tuple[str, str, str | None]]:
    """``(common name, role, robot or None)`` of every identity of a deployment: the roles of
    :data:`ROLES`, with :data:`ROBOT_ROLES` replaced by ``<role>-<robot>`` per robot if
    ``robots`` are named."""
    out: list[tuple[str, str, str | None]] = []
    for role in ROLES:
        if robots and role in ROBOT_ROLES:
            out += [(f"{role}-{robot}", role, robot) for robot in robots]
        else:
            out.append((role, role, None))
    return out


def parse_identity(common_name: str) -> tuple[str, str | None]:
    """``(role, robot or None)`` of a certificate common name (``agent``, ``simulator-ubot1``...).

    Raises:
        ValueError: a name that is no identity of a deployment.
    """
    if common_name in ROLES:
        return common_name, None
    role, sep, robot = common_name.partition("-")
    if sep and role in ROBOT_ROLES and robot:
        return role, robot
    raise ValueError(f"{common_name!r} is no ersac-hil identity (roles: {', '.join(ROLES)}, or "
                     f"{'/'.join(ROBOT_ROLES)}-<robot>)")


def access_control(prefix: str = DEFAULT_PREFIX, robot: str = "*", robots: Sequence[str] = (),
                   ros_domain: int = 0) -> dict[str, Any]:
    """The router's ``access_control`` section (Zenoh 1.10 schema) for the roles above.

    Args:
        prefix: the key prefix (one or more chunks).
        robot: one robot's key chunk, or ``*`` for every robot under ``prefix`` (the rules of
            the fleet-wide roles).
        robots: per-robot identities instead of the fleet-wide ``agent`` and ``simulator``
            (see the module doc); empty: none.
        ros_domain: the ROS domain of ``agent --ros2`` (``ros2_rules``).
    """
    rules, policies = [], []
    for name, role, own in identities(robots):
        chunk = robot if own is None else own
        ids = []
        for flow, grants in PERMISSIONS[role].items():
            for i, (messages, suffixes) in enumerate(grants):
                rule_id = f"{name}-{flow}-{i}"
                rules.append({
                    "id": rule_id, "permission": "allow", "flows": [flow],
                    "messages": list(messages),
                    "key_exprs": [f"{prefix}/{chunk}/{suffix}" for suffix in suffixes],
                })
                ids.append(rule_id)
        if role in CAN_ROLES:
            rules.append({"id": f"{name}-can", "permission": "allow", "flows": ["ingress", "egress"],
                          "messages": list(_CAN_MESSAGES),
                          "key_exprs": list(CAN_KEYS) if own is None else [f"can/{own}"]})
            ids.append(f"{name}-can")
        ros2 = ros2_rules(name, role, ros_domain, own)
        rules += ros2
        ids += [r["id"] for r in ros2]
        if ids:
            policies.append({"id": f"{name}-policy", "rules": ids, "subjects": [name]})
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": rules,
        "subjects": [{"id": name, "cert_common_names": [name]} for name, _, _ in identities(robots)],
        "policies": policies,
    }


# --------------------------------------------------------------------------- what a role may send
def permitted(role: str, message: str, suffix: str) -> bool:
    """May ``role`` send ``message`` (a Zenoh message kind: ``put``, ``query``...) on the key
    ``<prefix>/<robot>/<suffix>``? The ingress rules of :data:`PERMISSIONS`, so a client can
    refuse at once what the router would drop (``role`` as :func:`parse_identity` gives it)."""
    return any(message in messages and suffix in suffixes
               for messages, suffixes in PERMISSIONS.get(role, {}).get("ingress", ()))
