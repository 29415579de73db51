"""``ersac-hil certs init DIR``: a CA, one key and certificate per role, one Zenoh config per role.

Files (the convention other tools rely on)::

    DIR/ca.crt                 the CA certificate every role trusts
    DIR/ca.key                 the CA key (keep it on the machine that issues certificates)
    DIR/<role>.key             PKCS#8 P-256 private key (mode 0600)
    DIR/<role>.crt             certificate, common name = the role, signed by the CA
    DIR/<role>.json5           ready Zenoh config of the role (TLS with client certificates;
                               the router's also holds the access control of ersac_hil.roles)

for role in ``router``, ``daemon``, ``agent``, ``operator``, ``observer``, ``simulator``. Use a config with
``--zenoh-config DIR/<role>.json5`` on any command. :func:`role_of_config` tells the role of
a config file (the common name of its client certificate).

With ``--robot NAME`` (repeatable) the robot side is issued per robot instead:
``agent-NAME`` and ``simulator-NAME`` (files ``DIR/agent-NAME.*``...), each allowed only its
robot's keys and CAN channel (``ersac_hil.roles``: per-robot identities).
"""
from __future__ import annotations

import argparse
import datetime as dt
import ipaddress
import json
import os
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cryptography import x509
from cryptography.hazmat.primitives import hashes, serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

from ersac_hil.cli_args import add_prefix_argument, output_dir
from ersac_hil.roles import ROLES, access_control, identities
from ersac_hil.ros2.names import RosNameError, check_domain
from protocol.zenoh.keys import DEFAULT_PREFIX

__all__ = ["CertError", "CertSet", "init_certs", "role_of_config", "common_name", "router_config",
           "client_config", "register"]

DEFAULT_ROUTER = "tls/127.0.0.1:7447"
#: Roles whose certificate also serves TLS listeners (the router; a simulator's direct CAN
#: link, ``ersac_hil.canbus.direct``): they carry the router's host names.
LISTENING_ROLES = ("router", "simulator")
DEFAULT_DAYS = 825


class CertError(ValueError):
    """Certificates or configs that cannot be made or read."""


@dataclass(frozen=True)
class CertSet:
    """What :func:`init_certs` wrote. ``configs[role]`` is the role's json5 config."""

    directory: Path
    ca: Path
    configs: dict[str, Path]


def _name(common_name: str) -> x509.Name:
    return x509.Name([x509.NameAttribute(NameOID.ORGANIZATION_NAME, "ersac-hil"),
                      x509.NameAttribute(NameOID.COMMON_NAME, common_name)])


def _san(hosts: Sequence[str]) -> x509.SubjectAlternativeName:
    names: list[x509.GeneralName] = []
    for host in hosts:
        try:
            names.append(x509.IPAddress(ipaddress.ip_address(host)))
        except ValueError:
            names.append(x509.DNSName(host))
    return x509.SubjectAlternativeName(names)


def _issue(subject: str, key: ec.EllipticCurvePrivateKey, issuer_key: ec.EllipticCurvePrivateKey,
           issuer: x509.Name | None, days: int, hosts: Sequence[str] = ()) -> x509.Certificate:
    now = dt.datetime.now(dt.timezone.utc)
    ca = issuer is None
    builder = (x509.CertificateBuilder()
               .subject_name(_name(subject))
               .issuer_name(_name(subject) if ca else issuer)
               .public_key(key.public_key())
               .serial_number(x509.random_serial_number())
               .not_valid_before(now - dt.timedelta(minutes=5))
               .not_valid_after(now + dt.timedelta(days=days))
               .add_extension(x509.BasicConstraints(ca=ca, path_length=0 if ca else None), critical=True)
               .add_extension(x509.SubjectKeyIdentifier.from_public_key(key.public_key()), critical=False))
    if ca:
        builder = builder.add_extension(x509.KeyUsage(
            digital_signature=True, key_cert_sign=True, crl_sign=True, content_commitment=False,
            key_encipherment=False, data_encipherment=False, key_agreement=False,
            encipher_only=False, decipher_only=False), critical=True)
    else:
        builder = (builder
                   .add_extension(x509.KeyUsage(
                       digital_signature=True, key_cert_sign=False, crl_sign=False,
                       content_commitment=False, key_encipherment=False, data_encipherment=False,
                       key_agreement=True, encipher_only=False, decipher_only=False), critical=True)
                   .add_extension(x509.ExtendedKeyUsage(
                       [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                   .add_extension(x509.AuthorityKeyIdentifier.from_issuer_public_key(
                       issuer_key.public_key()), critical=False))
        if hosts:
            builder = builder.add_extension(_san(hosts), critical=False)
    return builder.sign(issuer_key, hashes.SHA256())


def _write(path: Path, data: bytes, private: bool = False) -> None:
    path.write_bytes(data)
    if private:
        os.chmod(path, 0o600)


def _key_pem(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _json5(comment: str, config: dict[str, Any]) -> bytes:
    head = "".join(f"// {line}\n" for line in comment.splitlines())
    return (head + json.dumps(config, indent=2) + "\n").encode()


_NO_SCOUTING = {"multicast": {"enabled": False}, "gossip": {"enabled": False}, "delay": 0}


def _tls(files: Path, **names: str) -> dict[str, Any]:
    """``transport.link.tls`` with the CA, the given key/certificate files, client certificates on."""
    tls = {"root_ca_certificate": str(files / "ca.crt"), **{k: str(files / v) for k, v in names.items()}}
    return {"link": {"tls": {**tls, "enable_mtls": True}}}


def router_config(files: Path, listen: Sequence[str], prefix: str = DEFAULT_PREFIX,
                  robots: Sequence[str] = (), ros_domain: int = 0) -> dict[str, Any]:
    """The router's Zenoh config: TLS listeners with client certificates required, the
    roles' access control (per-robot identities for ``robots``; ROS 2 on ``ros_domain``).
    ``files`` is where the key/cert files are (on the router)."""
    return {
        "mode": "router",
        "listen": {"endpoints": list(listen)},
        "connect": {"endpoints": []},
        "scouting": _NO_SCOUTING,
        "transport": _tls(files, listen_private_key="router.key", listen_certificate="router.crt"),
        "access_control": access_control(prefix, robots=robots, ros_domain=ros_domain),
    }


def client_config(role: str, files: Path, connect: Sequence[str]) -> dict[str, Any]:
    """A client role's Zenoh config: connect to the router over TLS with the role's certificate."""
    return {
        "mode": "client",
        "connect": {"endpoints": list(connect)},
        "listen": {"endpoints": []},
        "scouting": _NO_SCOUTING,
        "transport": _tls(files, connect_private_key=f"{role}.key", connect_certificate=f"{role}.crt"),
    }


def init_certs(directory: str | Path, *, router: Sequence[str] = (DEFAULT_ROUTER,),
               hosts: Sequence[str] = (), prefix: str = DEFAULT_PREFIX, install_dir: str | Path | None = None,
               days: int = DEFAULT_DAYS, force: bool = False, robots: Sequence[str] = (),
               ros_domain: int = 0) -> CertSet:
    """Create the CA, a key and certificate per role and a Zenoh json5 config per role.

    Args:
        directory: where to write (created if missing).
        router: the router's TLS endpoints (``tls/HOST:PORT``): where it listens and where the
            clients connect (the first one; edit a client's config to pick another).
        hosts: further names / addresses the router is reached at, for its certificate (the
            hosts of ``router`` are always included).
        prefix: the Zenoh key prefix the access control covers.
        install_dir: where the files will be on the machines (paths inside the configs);
            default: ``directory`` itself.
        days: validity of the certificates.
        force: overwrite an existing set.
        robots: issue ``agent-<robot>`` and ``simulator-<robot>`` per robot instead of the
            fleet-wide ``agent`` and ``simulator`` (``configs`` keyed by those names).
        ros_domain: the ROS domain (0..232) of the agents' ``--ros2`` that the access control
            lets through (``ersac_hil.roles.ros2_rules``).

    Raises:
        CertError: an existing set without ``force``, a bad endpoint or argument.
    """
    from ersac_hil.zenoh_session import ZenohConfigError, check_endpoint, split_endpoint
    from protocol.zenoh import KeySpace

    out = Path(directory)
    files = Path(install_dir) if install_dir is not None else out.resolve()
    if not router:
        raise CertError("the router needs at least one tls/HOST:PORT endpoint")
    router_hosts: list[str] = []
    for endpoint in router:
        try:
            protocol, host, _ = split_endpoint(check_endpoint(endpoint))
        except ZenohConfigError as exc:
            raise CertError(str(exc)) from None
        if protocol != "tls":
            raise CertError(f"router endpoint {endpoint!r} must be tls/HOST:PORT")
        router_hosts.append(host)
    if not 1 <= days <= 36_500:
        raise CertError(f"days must be in 1..36500, got {days}")
    try:
        check_domain(ros_domain)
    except RosNameError as exc:
        raise CertError(f"--ros-domain: {exc}") from None
    for robot in robots:
        try:
            KeySpace(robot, prefix)
        except ValueError as exc:
            raise CertError(f"robot {robot!r}: {exc}") from None
    if len(set(robots)) != len(robots):
        raise CertError(f"robots named twice: {sorted(r for r in set(robots) if list(robots).count(r) > 1)}")
    if out.exists() and not out.is_dir():
        raise CertError(f"{out} is a file, not a directory")
    if (out / "ca.crt").exists() and not force:
        raise CertError(f"{out} already holds a certificate set (ca.crt); use --force to replace it")
    out.mkdir(parents=True, exist_ok=True)
    ca_key = ec.generate_private_key(ec.SECP256R1())
    ca_cert = _issue("ersac-hil CA", ca_key, ca_key, None, days)
    _write(out / "ca.key", _key_pem(ca_key), private=True)
    _write(out / "ca.crt", ca_cert.public_bytes(serialization.Encoding.PEM))
    names = list(dict.fromkeys([*router_hosts, *hosts, "localhost", "127.0.0.1"]))
    configs = {}
    for name, role, robot in identities(robots):
        key = ec.generate_private_key(ec.SECP256R1())
        cert = _issue(name, key, ca_key, ca_cert.subject, days, names if role in LISTENING_ROLES else ())
        _write(out / f"{name}.key", _key_pem(key), private=True)
        _write(out / f"{name}.crt", cert.public_bytes(serialization.Encoding.PEM))
        if role == "router":
            config = router_config(files, router, prefix, robots, ros_domain)
            comment = ("Zenoh router of ersac-hil: TLS with client certificates, access control by role.\n"
                       "ersac-hil router --zenoh-config router.json5")
        else:
            config = client_config(name, files, router[:1])
            whose = f" of robot {robot}" if robot else ""
            comment = (f"Zenoh client config of the {role} role{whose} of ersac-hil.\n"
                       f"ersac-hil <command> --zenoh-config {name}.json5")
        path = out / f"{name}.json5"
        _write(path, _json5(comment, config))
        configs[name] = path
    return CertSet(out, out / "ca.crt", configs)


def role_of_config(path: str | Path) -> str | None:
    """The identity a Zenoh json5 config authenticates as: the common name of its client
    certificate (``transport/link/tls/connect_certificate``; a router's listen certificate),
    a role or a per-robot identity (``agent-ubot1``; ``ersac_hil.roles.parse_identity``),
    or ``None`` when it has no certificate (a plain loopback config).

    Raises:
        CertError: unreadable config or certificate.
    """
    import zenoh

    from ersac_hil.zenoh_session import zenoh_reason

    try:
        config = zenoh.Config.from_file(str(path))
    except (zenoh.ZError, ValueError, OSError) as exc:
        raise CertError(f"cannot read zenoh config {path}: {zenoh_reason(exc)}") from None
    cert_path = None
    for key in ("transport/link/tls/connect_certificate", "transport/link/tls/listen_certificate"):
        cert_path = json.loads(config.get_json(key))
        if cert_path:
            break
    if not cert_path:
        return None
    return common_name(cert_path, f" of {path}")


def common_name(cert_path: str | Path, where: str = "") -> str | None:
    """The common name of a PEM certificate file (``None`` if it has none).

    Raises:
        CertError: unreadable certificate (``where`` completes the message).
    """
    try:
        cert = x509.load_pem_x509_certificate(Path(cert_path).read_bytes())
    except (OSError, ValueError) as exc:
        raise CertError(f"cannot read certificate {cert_path}{where}: {exc}") from None
    names = cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)
    return str(names[0].value) if names else None


# --------------------------------------------------------------------------- CLI
def _init(args: argparse.Namespace) -> int:
    try:
        made = init_certs(args.dir, router=args.router or (DEFAULT_ROUTER,), hosts=args.host or (),
                          prefix=args.prefix, install_dir=args.install_dir, days=args.days,
                          force=args.force, robots=tuple(args.robot or ()), ros_domain=args.ros_domain)
    except (CertError, OSError) as exc:
        print(f"ersac-hil certs: {exc}", file=sys.stderr, flush=True)
        return 2
    print(f"CA and keys in {made.directory}; Zenoh configs:", flush=True)
    for name, path in made.configs.items():
        print(f"  {name:9s} {path}", flush=True)
    return 0


def register(sub: argparse._SubParsersAction) -> None:
    """Add ``certs init`` to the ``ersac-hil`` parser."""
    p = sub.add_parser("certs", help="certificates and Zenoh configs of the roles (mTLS + access control)")
    actions = p.add_subparsers(dest="certs_command", required=True)
    q = actions.add_parser("init", help=f"a CA, one key/cert and json5 config per role ({', '.join(ROLES)})")
    q.add_argument("dir", type=output_dir, help="directory to write into")
    q.add_argument("--router", action="append", metavar="ENDPOINT",
                   help=f"router TLS endpoint, repeatable (default {DEFAULT_ROUTER}); clients connect to the first")
    q.add_argument("--host", action="append", metavar="NAME",
                   help="another name or address the router is reached at (its certificate), repeatable")
    add_prefix_argument(q, "key prefix the access control covers")
    q.add_argument("--install-dir", metavar="PATH",
                   help="where the files will live on the machines (paths in the configs; default DIR)")
    q.add_argument("--days", type=int, default=DEFAULT_DAYS, help=f"validity (default {DEFAULT_DAYS})")
    q.add_argument("--force", action="store_true", help="replace an existing set")
    q.add_argument("--robot", action="append", metavar="NAME",
                   help="issue agent-NAME and simulator-NAME, allowed only robot NAME's keys and CAN channel "
                        "can/NAME, instead of the fleet-wide agent and simulator; repeatable")
    q.add_argument("--ros-domain", dest="ros_domain", type=int, default=0, metavar="N",
                   help="ROS domain (0..232) of the agents' --ros2 that the access control lets through (default 0)")
    q.set_defaults(func=_init)

