"""ersac-hil certs init: the file convention, the keys and certificates, role_of_config."""
from __future__ import annotations

import json
import stat

import pytest
from cryptography import x509
from cryptography.hazmat.primitives import serialization
from cryptography.hazmat.primitives.asymmetric import ec
from cryptography.x509.oid import NameOID

from ersac_hil.certs import CertError, init_certs, role_of_config
from ersac_hil.cli import main
from ersac_hil.roles import ROLES, access_control
from ersac_hil.zenoh_session import ZenohOptions, resolve_config


@pytest.fixture(scope="module")
def certs(tmp_path_factory):
    out = tmp_path_factory.mktemp("certs")
    init_certs(out, router=("tls/127.0.0.2:7447",), hosts=("robot.example",))
    return out


def test_files_follow_the_convention_and_are_sound(certs):
    ca = x509.load_pem_x509_certificate((certs / "ca.crt").read_bytes())
    assert ca.extensions.get_extension_for_class(x509.BasicConstraints).value.ca
    for role in ROLES:
        key_pem = (certs / f"{role}.key").read_bytes()
        assert key_pem.startswith(b"-----BEGIN PRIVATE KEY-----")  # PKCS#8, unencrypted
        key = serialization.load_pem_private_key(key_pem, None)
        assert isinstance(key, ec.EllipticCurvePrivateKey) and key.curve.name == "secp256r1"
        assert stat.S_IMODE((certs / f"{role}.key").stat().st_mode) == 0o600
        cert = x509.load_pem_x509_certificate((certs / f"{role}.crt").read_bytes())
        assert cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value == role
        assert cert.public_key().public_numbers() == key.public_key().public_numbers()
        cert.verify_directly_issued_by(ca)
        assert (certs / f"{role}.json5").is_file()
    router = x509.load_pem_x509_certificate((certs / "router.crt").read_bytes())
    san = router.extensions.get_extension_for_class(x509.SubjectAlternativeName).value
    assert "robot.example" in san.get_values_for_type(x509.DNSName)
    assert "127.0.0.2" in [str(a) for a in san.get_values_for_type(x509.IPAddress)]


def test_role_of_config_reads_the_certificate_name(certs, tmp_path):
    for role in ROLES:
        assert role_of_config(certs / f"{role}.json5") == role
    plain = tmp_path / "plain.json5"
    plain.write_text('{ mode: "client", connect: { endpoints: ["tcp/127.0.0.1:7447"] } }')
    assert role_of_config(plain) is None
    with pytest.raises(CertError):
        role_of_config(tmp_path / "missing.json5")


def test_configs_resolve_with_tls_and_access_control(certs):
    router = resolve_config(ZenohOptions(config_file=str(certs / "router.json5")), mode="router")
    assert json.loads(router.get_json("listen/endpoints")) == ["tls/127.0.0.2:7447"]
    assert json.loads(router.get_json("transport/link/tls/enable_mtls")) is True
    acl = json.loads(router.get_json("access_control"))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    expected = access_control("ersac")
    assert [(s["id"], s["cert_common_names"]) for s in acl["subjects"]] == [(r, [r]) for r in ROLES]
    assert [r["key_exprs"] for r in acl["rules"]] == [r["key_exprs"] for r in expected["rules"]]
    daemon = resolve_config(ZenohOptions(config_file=str(certs / "daemon.json5")))
    assert json.loads(daemon.get_json("connect/endpoints")) == ["tls/127.0.0.2:7447"]
    assert json.loads(daemon.get_json("transport/link/tls/connect_certificate")).endswith("daemon.crt")


def test_only_the_agent_and_the_simulator_are_on_the_can_bus():
    rules = {r["id"]: r for r in access_control()["rules"]}
    policies = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in access_control()["policies"]}

    def allowed(role, flow, message):
        return any(flow in r["flows"] and message in r["messages"] and "can/**" in r["key_exprs"]
                   for r in policies.get(role, []))
    for flow in ("ingress", "egress"):
        for message in ("put", "declare_subscriber"):
            assert [r for r in ROLES if allowed(r, flow, message)] == ["agent", "simulator"]
    assert [r["key_exprs"] for r in policies["simulator"]] == [["can/**"]]  # nothing else


def test_only_the_agent_may_serve_episodes_and_only_an_operator_steer():
    rules = {r["id"]: r for r in access_control()["rules"]}
    policies = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in access_control()["policies"]}

    def allowed(role, flow, message, suffix):
        return any(flow in r["flows"] and message in r["messages"] and f"ersac/*/{suffix}" in r["key_exprs"]
                   for r in policies.get(role, []))
    assert [r for r in ROLES if allowed(r, "ingress", "declare_queryable", "episode/run")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "reply", "episode/run")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "liveliness_token", "agent/alive")] == ["agent"]
    assert [r for r in ROLES if allowed(r, "ingress", "query", "episode/run")] == ["daemon"]
    for key in ("learner/kappa", "learner/weights"):
        assert [r for r in ROLES if allowed(r, "ingress", "put", key)] == ["operator"]
    assert [r for r in ROLES if allowed(r, "ingress", "query", "learner/select")] == ["operator"]
    assert [r for r in ROLES if allowed(r, "ingress", "declare_queryable", "learner/state")] == ["daemon"]


def test_cli_refuses_an_existing_set_and_plain_endpoints(certs, tmp_path, capsys):
    assert main(["certs", "init", str(certs)]) == 2
    assert "--force" in capsys.readouterr().err
    assert main(["certs", "init", str(tmp_path / "x"), "--router", "tcp/127.0.0.1:7447"]) == 2
    assert "tls/" in capsys.readouterr().err
    assert not (tmp_path / "x").exists()
    assert main(["certs", "init", str(tmp_path / "y")]) == 0
    assert role_of_config(tmp_path / "y" / "observer.json5") == "observer"
    with pytest.raises(CertError, match="days"):
        init_certs(tmp_path / "z", days=0)


def test_permitted_is_the_routers_own_ingress_rules():
    from ersac_hil.roles import PERMISSIONS, permitted
    rules = {r["id"]: r for r in access_control()["rules"]}
    policies = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in access_control()["policies"]}
    kinds = {m for grants in PERMISSIONS.values() for flow in grants.values() for ms, _ in flow for m in ms}
    suffixes = {s for grants in PERMISSIONS.values() for flow in grants.values() for _, ss in flow for s in ss}
    for role in ROLES:
        for message in kinds:
            for suffix in suffixes:
                allowed = any("ingress" in r["flows"] and message in r["messages"]
                              and f"ersac/*/{suffix}" in r["key_exprs"] for r in policies.get(role, []))
                assert permitted(role, message, suffix) == allowed, (role, message, suffix)


# what one side sends -> what the router must deliver to each side of the exchange
_EXCHANGES = [  # (sender's kind, receiver's kind, told to the sender, delivered to the receiver)
    ("put", "declare_subscriber", "declare_subscriber", "put"),
    ("query", "declare_queryable", "declare_queryable", "query"),
    ("query", "declare_queryable", "reply", "query"),
    ("liveliness_token", "declare_liveliness_subscriber", None, "liveliness_token"),
]


@pytest.mark.parametrize("robots", [(), ("ubot1",)])
def test_every_exchange_the_roles_may_start_is_delivered_both_ways(robots):
    """Wherever one identity may send (put, query, a token) and another may receive it on the
    same key, the router's egress rules deliver it to the receiver and tell the sender of the
    receiver (subscriber, queryable), and return the replies: a grant to send is never left
    without what it needs back (the ROS 2 agent once dropped every sample after the first)."""
    acl = access_control(robots=robots)
    rules = {r["id"]: r for r in acl["rules"]}
    grants = {p["subjects"][0]: [rules[i] for i in p["rules"]] for p in acl["policies"]}

    def allows(name, flow, message, key):
        return any(flow in r["flows"] and message in r["messages"] and key in r["key_exprs"]
                   for r in grants.get(name, []))

    keys = {k for r in acl["rules"] for k in r["key_exprs"]}
    checked = 0
    for sends, receives, told, delivered in _EXCHANGES:
        for key in keys:
            for a in grants:
                for b in grants:
                    if a != b and allows(a, "ingress", sends, key) and allows(b, "ingress", receives, key):
                        assert allows(b, "egress", delivered, key), (b, delivered, key)
                        assert told is None or allows(a, "egress", told, key), (a, told, key)
                        checked += 1
    assert checked > 20


@pytest.mark.parametrize("argv, refusal", [
    (("kappa", "set", "0.5"), "observer may not set kappa"),
    (("weights", "set", "damage=5"), "observer may not set the weights"),
    (("select", "--kappa", "1"), "observer may not select a policy"),
])
def test_an_observer_is_refused_by_its_role_before_any_session(certs, argv, refusal, capsys):
    """Nothing listens at the configs' router (tls/127.0.0.2:7447): a command that opened a
    session would fail with exit 1 ("cannot open a zenoh session"); the role refuses first."""
    code = main([*argv, "--zenoh-config", str(certs / "observer.json5")])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and refusal in err[0], err


def test_the_client_knows_its_role(certs, tmp_path):
    from ersac_hil.daemon.clients import NotPermitted, check_permitted, identity_role
    assert identity_role(ZenohOptions(config_file=str(certs / "observer.json5"))) == "observer"
    assert identity_role(ZenohOptions(config_file=str(certs / "operator.json5"))) == "operator"
    assert identity_role(ZenohOptions(("tcp/127.0.0.1:7447",))) is None  # no certificate: not checked
    check_permitted(None, "kappa")
    for action in ("state", "critic", "select", "episodes", "kappa", "weights"):
        check_permitted("operator", action)
    check_permitted("observer", "critic")
    with pytest.raises(NotPermitted, match="daemon may not set kappa"):
        check_permitted("daemon", "kappa")
