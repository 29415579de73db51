"""Which agents are there behind a router: the start of a command that runs its work on
simulator/agent pairs already running elsewhere (``reproduce --agents``, ``bench/bracing_sweep.py
--agents``, ``bench/fleet.py --agents``). :func:`reach_agents` opens a session with the
command's Zenoh options and gives the robots whose agents a source (a name or a one-chunk key
expression of names) shows and that are ready, or refuses with :class:`NoAgents` in one line
saying why: the configuration, the identity's role, the session, or how many answered."""
from __future__ import annotations

import threading
import time

import zenoh

from ersac_hil.zenoh_session import (EndpointError, ZenohConfigError, ZenohOptions, ZenohSessionError, open_session,
                                     resolve_config)
from protocol.zenoh import KeySpace

from .agents import AgentLink, Stopped

__all__ = ["NoAgents", "find_agents", "is_robot", "reach_agents", "robot_of"]


class NoAgents(RuntimeError):
    """No agent of a source is usable, in one line: none answered within the wait, those that
    answered take no episode from this identity, its role may not request episodes, or its
    Zenoh configuration or session does not work."""


def robot_of(key: str, prefix: str) -> str:
    """The robot chunk of ``<prefix>/<robot>/agent/alive``."""
    return key[len(prefix) + 1: -len("/agent/alive")]


def is_robot(robot: str, prefix: str) -> bool:
    """``robot`` is a valid robot name under ``prefix`` (a key a pattern matched may not be)."""
    try:
        KeySpace(robot, prefix)
    except ValueError:
        return False
    return True


def _alive(session: zenoh.Session, key: str, prefix: str, timeout_s: float) -> list[str]:
    """The robots (sorted) whose ``agent/alive`` token on ``key`` the router knows of now."""
    robots = set()
    for reply in session.liveliness().get(key, timeout=max(timeout_s, 0.1)):
        if reply.ok is not None:
            robot = robot_of(str(reply.ok.key_expr), prefix)
            if is_robot(robot, prefix):
                robots.add(robot)
    return sorted(robots)


def find_agents(session: zenoh.Session, prefix: str, source: str, wait_s: float,
                stop: threading.Event) -> list[str]:
    """The robots (sorted) whose agents answer ``<prefix>/<source>/agent/alive`` and are ready
    (``AgentLink.ready``: presence, session and a reachable ``episode/run``) within ``wait_s``:
    every agent the router knows of as soon as all of them are ready, else at ``wait_s`` those
    that are. Raises :class:`NoAgents` (none ready: the message says how many answered) or
    ``Stopped``."""
    key = f"{prefix}/{source}/agent/alive"
    deadline = time.monotonic() + wait_s
    links: dict[str, AgentLink] = {}
    try:
        while True:
            if stop.is_set():
                raise Stopped
            for robot in _alive(session, key, prefix, min(deadline - time.monotonic(), 5.0)):
                if robot not in links:
                    links[robot] = AgentLink(session, KeySpace(robot, prefix), 1.0, stop)
            ready = sorted(robot for robot, link in links.items() if link.ready())
            if links and len(ready) == len(links):
                return ready
            if time.monotonic() >= deadline:
                if ready:
                    return ready
                if links:
                    raise NoAgents(
                        f"{len(links)} agent(s) answered on {key} ({', '.join(sorted(links))}) but none takes "
                        f"episode requests from this identity within {wait_s:g} s: not permitted (the router "
                        "routes no episode/run query of it to them), or their episode/run is not up yet")
                others = _alive(session, f"{prefix}/*/agent/alive", prefix, 5.0)
                raise NoAgents(f"no agent answered on {key} within {wait_s:g} s (0 answered; "
                               + (f"agents of other robots under {prefix}/ did: {', '.join(others)})" if others else
                                  f"no agent at all under {prefix}/: is it the router of the pairs?)"))
            stop.wait(0.05)
    finally:
        for link in links.values():
            link.close()


def reach_agents(options: ZenohOptions, source: str, prefix: str, wait_s: float, stop: threading.Event) -> list[str]:
    """:func:`find_agents` through a session opened with ``options`` (``--zenoh``,
    ``--zenoh-config``, ``--insecure``) and closed again. Refused with :class:`NoAgents`, in
    this order: a configuration that cannot be read or used; an identity whose role may not
    request episodes ("not permitted", before anything is sent: ``clients.check_permitted``);
    a session the router refuses or that reaches nothing; no agent ready."""
    from .clients import NotPermitted, check_permitted, identity_role

    try:
        config = resolve_config(options)
        role = identity_role(options)
        check_permitted(role, "run")
        session = open_session(config, insecure=options.insecure)
    except NotPermitted as exc:
        raise NoAgents(f"not permitted: {exc}") from None
    except (ZenohConfigError, EndpointError, ZenohSessionError) as exc:
        raise NoAgents(str(exc)) from None
    try:
        return find_agents(session, prefix, source, wait_s, stop)
    except NoAgents as exc:
        name = _certificate_name(options) if role is None else None
        if name is None:
            raise
        raise NoAgents(f"{exc}; not permitted? this identity, {name!r}, is no role of ersac_hil.roles, and a "
                       "router's access control drops unseen what an identity may not do") from None
    finally:
        session.close()


def _certificate_name(options: ZenohOptions) -> str | None:
    """The common name of the client certificate of ``options``' config file, if any."""
    from ersac_hil.certs import CertError, role_of_config

    try:
        return role_of_config(options.config_file) if options.config_file else None
    except CertError:
        return None
