"""The listening side of a direct CAN-over-Zenoh link (``ZenohBus(listen=...)``).

A bus opened with ``listen=ENDPOINT`` is a Zenoh peer that listens there and connects nowhere
(unless its channel names endpoints); the other buses of the channel connect to it as clients
(``channel="name@ENDPOINT"``), so their frames go straight to it instead of through the
router: one router hop less each way (a simulator listens, its agent connects).

The listener enforces what the router enforces for the CAN bus:

* a plain endpoint only on loopback (``insecure`` otherwise, like every session);
* with a TLS identity (``zenoh_config``, e.g. ``certs/simulator.json5``): every listen endpoint
  must be ``tls/``; the role's certificate is the listener's (``certs init`` gives the
  simulator's the router's host names), client certificates are required (mTLS), and the
  router's access control (``ersac_hil.roles.access_control``, default deny) applies to every
  link: only the ``agent`` and ``simulator`` roles may send and receive frames on ``can/**``;
  a per-robot listener identity (``simulator-ubot1``, ``certs init --robot ubot1``) admits only
  its robot's identities, on ``can/ubot1``. A config file that sets its own ``access_control``
  keeps it.
"""
from __future__ import annotations

import json
from collections.abc import Sequence

import zenoh

from ersac_hil.roles import access_control, parse_identity
from ersac_hil.zenoh_session import (SECURE_PROTOCOLS, ZenohConfigError, ZenohOptions, resolve_config,
                                     split_endpoint, zenoh_reason)

__all__ = ["listener_config"]

_TLS = "transport/link/tls"


def listener_config(options: ZenohOptions, listen: Sequence[str], *,
                    connect_timeout_s: float | None = None) -> zenoh.Config:
    """The session config of a bus listening on ``listen`` (see the module doc);
    ``options.endpoints`` are where it also connects (usually none).

    Raises:
        ZenohConfigError: a bad or unsecured endpoint, a TLS listener without a certificate,
            a TLS identity on a plain listener.
    """
    if not listen:
        raise ZenohConfigError("a listening CAN bus needs at least one endpoint")
    config = resolve_config(options, mode="peer", listen=listen, connect_timeout_s=connect_timeout_s)
    _set(config, "connect/endpoints", list(options.endpoints))
    secure = [split_endpoint(ep)[0] in SECURE_PROTOCOLS for ep in listen]
    identity = _get(config, f"{_TLS}/connect_certificate") or _get(config, f"{_TLS}/listen_certificate")
    if identity and not all(secure):
        raise ZenohConfigError(f"{options.config_file} gives a TLS identity: listen on tls/HOST:PORT, "
                               f"not {', '.join(ep for ep, s in zip(listen, secure) if not s)}")
    if any(secure):
        if not identity or not _get(config, f"{_TLS}/root_ca_certificate"):
            raise ZenohConfigError("a TLS CAN listener needs a certificate and the CA "
                                   "(zenoh_config=certs/simulator.json5 from 'ersac-hil certs init')")
        for what in ("certificate", "private_key"):
            if not _get(config, f"{_TLS}/listen_{what}"):
                _set(config, f"{_TLS}/listen_{what}", _get(config, f"{_TLS}/connect_{what}"))
        _set(config, f"{_TLS}/enable_mtls", True)
        if not _get(config, "access_control/enabled"):
            _set(config, "access_control", _listener_access(identity))
    return config


def _listener_access(certificate: str) -> dict:
    """The router's access control, for the robot of a per-robot listener identity only."""
    from ersac_hil.certs import CertError, common_name
    try:
        name = common_name(certificate)
    except CertError as exc:
        raise ZenohConfigError(str(exc)) from None
    try:
        _, robot = parse_identity(name or "")
    except ValueError:
        robot = None  # a certificate of another CA's naming: the fleet-wide rules
    return access_control(robots=(robot,) if robot else ())


def _get(config: zenoh.Config, key: str):  # noqa: ANN202 - JSON value
    return json.loads(config.get_json(key))


def _set(config: zenoh.Config, key: str, value: object) -> None:
    try:
        config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise ZenohConfigError(f"invalid zenoh config value at {key}: {zenoh_reason(exc)}") from None
