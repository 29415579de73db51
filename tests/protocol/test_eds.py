import subprocess
import sys
from pathlib import Path

from canopen.objectdictionary import ODVariable

from protocol.can.bench import BENCH, object_dictionary
from protocol.can.pdo import pdo_maps

ROOT = Path(__file__).resolve().parents[2]


def test_committed_eds_files_match_generator():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_eds.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, r.stdout + r.stderr


def test_every_device_has_identity_heartbeat_and_status():
    for dev in BENCH:
        od = object_dictionary(dev)
        for index in (0x1000, 0x1001, 0x1016, 0x1017, 0x1018, 0x2010):
            assert index in od, (dev.name, hex(index))


def test_pdo_entries_are_mappable_and_fit_a_frame():
    for dev in BENCH:
        od = object_dictionary(dev)
        for p in pdo_maps(dev):
            assert p.length <= 8
            for e in p.entries:
                var = od[e.index] if isinstance(od[e.index], ODVariable) else od[e.index][e.subindex]
                assert var.pdo_mappable, (dev.name, p.direction, p.number, e.name)
                assert len(var) == e.bits
                if p.direction == "tpdo":
                    assert var.readable
                else:
                    assert var.writable


def test_cob_ids_unique_on_the_bench():
    cobs = [p.cob_id for d in BENCH for p in pdo_maps(d)]
    assert len(cobs) == len(set(cobs))
    assert len({d.node_id for d in BENCH}) == len(BENCH)


def test_protocol_doc_is_current():
    r = subprocess.run([sys.executable, str(ROOT / "tools" / "gen_protocol_doc.py"), "--check"],
                       capture_output=True, text=True)
    assert r.returncode == 0, "docs/protocol.md is stale: run python tools/gen_protocol_doc.py"
