import subprocess
import sys

import pytest

from protocol.can.busload import bus_load, frame_bits


def test_frame_bits_worst_case_stuffing():
    assert frame_bits(0) == 55    # SYNC
    assert frame_bits(8) == 135   # 8-byte PDO, Davis et al. 2007
    assert [frame_bits(n + 1) - frame_bits(n) for n in range(8)] == [10] * 8
    with pytest.raises(ValueError):
        frame_bits(9)


def test_cyclic_schedule_within_half_the_bus_at_200hz():
    load = bus_load(200.0, 1_000_000)
    assert load.within_budget, f"{load.percent:.1f} %"
    # every synchronous PDO of the devices is in the budget, plus SYNC and heartbeats
    assert sum(1 for i in load.items if "PDO" in i.name) == 17


def test_load_scales_with_rate():
    assert bus_load(400.0).percent == pytest.approx(2 * bus_load(200.0).percent, rel=0.02)


def test_cli_prints_budget_line():
    out = subprocess.run([sys.executable, "-m", "ersac_hil.cli", "bus-load", "--rate", "200",
                          "--bitrate", "1000000", "--check"], capture_output=True, text=True, check=True)
    last = out.stdout.strip().splitlines()[-1]
    assert last.startswith("bus load: ") and last.endswith("% at 1000000 bit/s, 200 Hz")
    assert float(last.split()[2].rstrip("%")) <= 50.0
