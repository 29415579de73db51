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


def test_event_timer_tpdos_count_at_their_timer():
    """A CiA 402 drive's TPDO1 (statusword and mode, event-driven) goes out every 100 ms (its
    0x1800:5) whatever the SYNC: seven 3-byte frames at 10 Hz on the ubot5-cia402, none on the
    boards."""
    from protocol.robot import load_description
    robot = load_description("ubot5-cia402")
    for rate in (100.0, 200.0, 400.0):
        load = bus_load(rate, description=robot)
        timed = [i for i in load.items if i.name.endswith(" every 100 ms")]
        assert len(timed) == 7 and all(i.name.split()[1] == "TPDO1" and i.data_bytes == 3 for i in timed)
        assert all(i.per_cycle == pytest.approx(10.0 / rate) for i in timed)
        assert sum(i.bits_per_cycle for i in timed) * rate == pytest.approx(7 * 10 * frame_bits(3))
    assert not [i for i in bus_load(description=load_description("ubot5")).items if " every " in i.name]
    # the timers are per second: they do not scale with the SYNC rate, the cyclic frames do
    assert bus_load(400.0, description=robot).max_rate_hz == pytest.approx(bus_load(200.0, description=robot).max_rate_hz)
