"""``ersac-hil sim`` as a process on the loopback hub: boots its nodes, answers SDO, and
shuts down cleanly on SIGTERM and SIGINT."""
from __future__ import annotations

import signal
import subprocess
import sys

import pytest

from ersac_hil.canbus import LoopbackHub
from helpers.waiting import wait_until
from protocol.can.devices import DEVICES, TESTBENCH, object_dictionary
from protocol.can.busconfig import open_network

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_sim_process_serves_the_bench_and_stops_on_signal(sig):
    with LoopbackHub() as hub:
        net = open_network(hub.bus_config)
        booted: set[int] = set()
        for d in DEVICES:
            net.subscribe(0x700 + d.node_id, lambda cid, data, ts: booted.add(cid & 0x7F))
        proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "sim", "--bus-interface", "remote",
                                 "--bus-channel", hub.url, "--seed", "3"],
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            assert proc.stdout.readline().startswith("simulator: 6 nodes on remote:")
            wait_until(lambda: booted == {d.node_id for d in DEVICES}, what="the boot-up of every node")
            tb = net.add_node(TESTBENCH.node_id, object_dictionary(TESTBENCH))
            assert tb.sdo[0x1018][2].raw == object_dictionary(TESTBENCH)[0x1018][2].default
            proc.send_signal(sig)
            out, err = proc.communicate(timeout=10)
        finally:
            if proc.poll() is None:
                proc.kill()
                proc.wait()
            net.disconnect()
        assert proc.returncode == 128 + sig, err
        assert "simulator stopped" in out
        assert "Traceback" not in err


def test_bad_bus_config_is_refused_clearly():
    r = subprocess.run([sys.executable, "-m", "firmware_sim", "--bus-interface", "remote",
                        "--bus-channel", "ws://10.0.0.1:9/"], capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "loopback" in r.stderr


def test_snapshot_renders_a_png_headlessly(tmp_path):
    out = tmp_path / "bracing.png"
    r = subprocess.run([sys.executable, "-m", "firmware_sim", "--snapshot", str(out), "--scenario", "bracing",
                        "--at", "0.1"], capture_output=True, text=True, timeout=120)
    if r.returncode == 2 and "headless rendering needs" in r.stderr:
        pytest.skip(f"no headless GL here: {r.stderr.strip().splitlines()[-1]}")
    assert r.returncode == 0, r.stderr
    data = out.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n" and len(data) > 10_000  # a real frame, not a blank stub
