"""Zenoh sessions: one configuration resolver, a checked session opener, an embedded router.

Every session this project opens goes through :func:`resolve_config` (command lines: a Zenoh
json5 file ``--zenoh-config``, endpoints ``--zenoh``, ``--insecure``) or :func:`make_config`
(code and tests), then :func:`open_session`, which enforces the rules:

* explicit endpoints only: ``listen/endpoints`` is always set (Zenoh's default listener is
  ``tcp/[::]:0`` on every interface);
* an endpoint off loopback must be secured (``tls/`` or ``quic/``: TLS, with the certificates
  of the json5 file); a plain one is refused unless the user says ``insecure``;
* multicast scouting off unless a config file turns it on *and* ``insecure`` is given; gossip
  scouting off unless asked for; no scouting delay (the default 500 ms only waits for
  multicast replies we never send);
* a bare ``zenoh.Config()`` is refused.

Typical use::

    with EmbeddedRouter() as router:                       # router on 127.0.0.1:<free port>
        with session_scope(router.client_config()) as s:   # closed on exit, even on error
            s.put("ersac/ubot1/learner/kappa", KappaCommand(0.5).to_json())

A router for other processes (CLI): ``EmbeddedRouter(port=7447).start().wait()``.

One module a job: ``endpoints`` (the endpoint policy), ``config`` (building and checking
configurations), ``session`` (opening), ``args`` (the command-line flags), ``router`` (the
embedded router), ``errors``; this package's face is the API above.
"""

from .args import add_zenoh_arguments, zenoh_argv, zenoh_options
from .config import BURSTS, MODES, ZenohOptions, check_config, make_config, resolve_config, tolerate_bursts
from .endpoints import (DEFAULT_ENDPOINT, SECURE_PROTOCOLS, check_endpoint, free_tcp_port, is_loopback,
                        loopback_endpoint, split_endpoint)
from .errors import EndpointError, ZenohConfigError, ZenohSessionError, zenoh_reason
from .router import EmbeddedRouter
from .session import open_session, session_scope

__all__ = [
    "MODES",
    "BURSTS",
    "tolerate_bursts",
    "DEFAULT_ENDPOINT",
    "SECURE_PROTOCOLS",
    "ZenohOptions",
    "add_zenoh_arguments",
    "zenoh_argv",
    "zenoh_options",
    "resolve_config",
    "is_loopback",
    "split_endpoint",
    "ZenohConfigError",
    "EndpointError",
    "ZenohSessionError",
    "zenoh_reason",
    "loopback_endpoint",
    "check_endpoint",
    "free_tcp_port",
    "make_config",
    "check_config",
    "open_session",
    "session_scope",
    "EmbeddedRouter",
]
