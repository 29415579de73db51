import math

import pytest
from hypothesis import given
from hypothesis import strategies as st

from protocol.can import cobid
from protocol.can.busconfig import BusConfig, BusConfigError, parse_bus_kwargs, resolve_bus_config
from protocol.can.objects import POSITION, STIFFNESS, WHEEL_POSITION, Scale

node_ids = st.integers(1, 127)


@given(node_ids, st.integers(1, 4))
def test_classify_inverts_pdo_cob_ids(node, n):
    assert cobid.classify(cobid.tpdo(n, node)) == cobid.CobIdInfo(f"TPDO{n}", node)
    assert cobid.classify(cobid.rpdo(n, node)) == cobid.CobIdInfo(f"RPDO{n}", node)


@given(node_ids)
def test_classify_inverts_services(node):
    assert cobid.classify(cobid.emcy(node)).function == "EMCY"
    assert cobid.classify(cobid.sdo_tx(node)).function == "SDO-TX"
    assert cobid.classify(cobid.sdo_rx(node)).function == "SDO-RX"
    assert cobid.classify(cobid.heartbeat(node)) == cobid.CobIdInfo("HEARTBEAT", node)


@pytest.mark.parametrize("bad", [0, 128, -1])
def test_node_id_range(bad):
    with pytest.raises(ValueError):
        cobid.heartbeat(bad)


@given(st.floats(-3.2, 3.2))
def test_scale_round_trip_within_resolution(x):
    assert abs(POSITION.from_raw(POSITION.to_raw(x)) - x) <= POSITION.factor / 2 + 1e-12


@given(st.floats(allow_nan=False))
def test_scale_saturates_instead_of_wrapping(x):
    for scale in (POSITION, WHEEL_POSITION, STIFFNESS):
        raw = scale.to_raw(x)
        assert scale.raw_min <= raw <= scale.raw_max
        if x > 0:
            assert raw >= 0


def test_scale_refuses_nan():
    with pytest.raises(ValueError):
        Scale(1.0, "x").to_raw(math.nan)


@pytest.mark.parametrize("url", ["ws://10.1.2.3:5000/", "ws://example.com:1/", "http://127.0.0.1:1/"])
def test_remote_hub_must_be_loopback(url):
    with pytest.raises(BusConfigError):
        BusConfig("remote", url)


def test_multicast_backend_refused():
    with pytest.raises(BusConfigError):
        BusConfig("udp_multicast", "239.0.0.1")


def test_resolve_keeps_explicit_values():
    cfg = resolve_bus_config("remote", "ws://127.0.0.1:5000/", 500000)
    assert cfg == BusConfig("remote", "ws://127.0.0.1:5000/", 500000)


def test_bus_kwargs_reach_the_interface_as_strings():
    options = parse_bus_kwargs(["zenoh_config=/etc/agent.json5", "insecure=false", "insecure=true"])
    assert options == (("zenoh_config", "/etc/agent.json5"), ("insecure", "true"))  # the last one wins
    cfg = resolve_bus_config("zenoh", "c@tcp/127.0.0.1:7447", None, options)
    kwargs = cfg.kwargs()  # python-can's resolution reads "true" as True: the interface gets "True"
    assert kwargs["zenoh_config"] == "/etc/agent.json5" and kwargs["insecure"].lower() == "true"
    assert (kwargs["interface"], kwargs["channel"]) == ("zenoh", "c@tcp/127.0.0.1:7447")


@pytest.mark.parametrize("item, match", [("novalue", "not KEY=VALUE"), ("1x=2", "not KEY=VALUE"),
                                         ("channel=can1", "--bus-channel")])
def test_bad_bus_kwargs_are_refused(item, match):
    with pytest.raises(BusConfigError, match=match):
        parse_bus_kwargs([item])
