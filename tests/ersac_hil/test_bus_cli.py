"""``ersac-hil bus``: a loopback hub process that relays frames, prints them with --monitor,
and stops cleanly on SIGINT/SIGTERM."""
from __future__ import annotations

import signal
import subprocess
import sys

import can
import pytest

pytestmark = pytest.mark.timeout(60)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGTERM])
def test_hub_process_relays_and_monitors_then_stops(sig):
    proc = subprocess.Popen([sys.executable, "-m", "ersac_hil.cli", "bus", "--monitor"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    buses = []
    try:
        first = proc.stdout.readline().strip()
        assert first.startswith("CAN hub: ws://127.0.0.1:")
        url = first.split(": ", 1)[1]
        a, b = (can.Bus(interface="remote", channel=url) for _ in range(2))
        buses += [a, b]  # the hub's first line comes once its monitor is connected
        a.send(can.Message(arbitration_id=0x190, data=bytes(range(8)), is_extended_id=False))
        got = b.recv(2.0)
        assert got is not None and got.arbitration_id == 0x190 and bytes(got.data) == bytes(range(8))
        line = proc.stdout.readline()
        assert "190 TPDO1" in line and "wheels" in line and "00 01 02 03 04 05 06 07" in line
        while buses:  # clients leave before the hub does
            buses.pop().shutdown()
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=10)
    finally:
        for bus in buses:
            bus.shutdown()
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 128 + sig, err
    assert "CAN hub stopped" in out
