"""``ersac-hil commission`` against the simulated robot (the uBot on its boards, every node on a
virtual bus): the right description passes and writes the record; each defect of a
deliberately wrong description is reported in one line, with exit status 1 and no record."""
from __future__ import annotations

import json
import uuid
from pathlib import Path

import pytest

from ersac_hil.cli import main
from ersac_hil.commission.fingerprint import recorded
from helpers.can_nodes import Master
from helpers.timing import PATIENCE_MS, patient_controllers
from protocol.can.devices import DEVICES
from firmware_sim.controllers.boards import BOARDS
from firmware_sim.nodes.simrobot import SimulatedRobot
from protocol.can.busconfig import BusConfig
from protocol.robot.load import SHIPPED_DIR
from protocol.robot.model import SHIPPED_EDS_DIR

pytestmark = pytest.mark.timeout(120)
UBOT5 = (SHIPPED_DIR / "ubot5.toml").read_text()


@pytest.fixture(scope="module")
def robot():
    bus = BusConfig("virtual", f"commission-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(bus) as sim:
        master = Master(bus, DEVICES)
        try:
            patient_controllers(master.nodes.values())  # --move's heartbeat may stall under load
        finally:
            master.close()
        yield bus, sim


def run(bus: BusConfig, description: str, record: Path, capsys, *more: str) -> tuple[int, list[str]]:
    code = main(["commission", "--description", description, "--bus-interface", bus.interface,
                 "--bus-channel", bus.channel, "--commission-record", str(record),
                 "--sdo-timeout-ms", str(PATIENCE_MS), *more])  # a loaded machine answers late
    out = capsys.readouterr()
    return code, (out.out + out.err).splitlines()


def wrong(tmp_path: Path, old: str, new: str, name: str = "wrong.toml") -> str:
    assert old in UBOT5
    path = tmp_path / name
    path.write_text(UBOT5.replace(old, new, 1))
    return str(path)


def defects(lines: list[str]) -> list[str]:
    return [line for line in lines if line.startswith("DEFECT")]


def test_the_right_description_passes_and_is_recorded(robot, tmp_path, capsys):
    bus, sim = robot
    record = tmp_path / "state" / "ubot5.json"
    code, lines = run(bus, "ubot5", record, capsys)
    assert code == 0, lines
    # one record line naming the file (not necessarily the last: stderr may hold other threads' output)
    assert defects(lines) == [] and [line for line in lines if line.startswith("record: ")] == [f"record: {record}"]
    assert any(line.startswith("PASS") for line in lines)
    assert sum(line.startswith("axis ") for line in lines) == 7  # every axis read once
    body = json.loads(record.read_text())
    assert body["description"] == "ubot5" and len(body["nodes"]) == 5  # the robot's nodes, no bench
    assert recorded(record) == body["fingerprint"] and len(body["fingerprint"]) == 64
    assert sim.stats.cycles == 0  # no SYNC: nothing stepped, nothing moved


def test_a_missing_node_is_one_line(robot, tmp_path, capsys):
    bus, _ = robot
    path = wrong(tmp_path, 'node_id = 0x20\neds = "imu.eds"', 'node_id = 0x30\neds = "imu.eds"')
    code, lines = run(bus, path, tmp_path / "r.json", capsys)
    assert code == 1 and not (tmp_path / "r.json").exists()
    assert "DEFECT missing node: imu 0x30: does not answer an SDO read of 0x1000" in defects(lines)
    assert any(d.startswith("DEFECT extra node: node 0x20:") for d in defects(lines))  # what is there instead


def test_a_wrong_device_type_is_one_line(robot, tmp_path, capsys):
    bus, _ = robot
    path = wrong(tmp_path, 'node_id = 0x20\neds = "imu.eds"', 'node_id = 0x20\neds = "testbench.eds"')
    code, lines = run(bus, path, tmp_path / "r.json", capsys)
    assert code == 1
    assert defects(lines) == ["DEFECT wrong device type: imu 0x20: product code 0x1018:2 is 0x00000004, "
                              "its EDS says 0x000000F0"]


def test_a_wrong_pdo_map_is_one_line(robot, tmp_path, capsys):
    bus, _ = robot
    eds = (SHIPPED_EDS_DIR / "arm.eds").read_text()
    swapped = eds.replace("DefaultValue=0x20000110", "DefaultValue=@").replace(
        "DefaultValue=0x20000210", "DefaultValue=0x20000110").replace("DefaultValue=@", "DefaultValue=0x20000210")
    assert swapped != eds
    (tmp_path / "arm_swapped.eds").write_text(swapped)
    path = wrong(tmp_path, '[nodes.arm_left]\nnode_id = 0x12\nprofile = "ubot-board"\neds = "arm.eds"',
                 f'[nodes.arm_left]\nnode_id = 0x12\nprofile = "ubot-board"\neds = "{tmp_path / "arm_swapped.eds"}"')
    code, lines = run(bus, path, tmp_path / "r.json", capsys)
    assert code == 1
    (line,) = defects(lines)
    assert line.startswith("DEFECT wrong PDO map: arm_left 0x12: TPDO1 is COB-ID 0x192 type 1 [2000:1/16 2000:2/16")
    assert "the EDS has COB-ID 0x192 type 1 [2000:2/16 2000:1/16" in line


def test_a_limit_outside_the_drives_is_one_line(robot, tmp_path, capsys):
    bus, _ = robot
    old = 'label = "elbow"\nmode = "impedance"\ngear = 120.0\ntorque_constant = 0.0259\nback_emf = 0.0259\n' \
          'resistance = 0.611\nposition_limits = [-0.1, 2.6]\nvelocity_limit = 10.0\ncurrent_limit = 12.0'
    path = wrong(tmp_path, old, old.replace("current_limit = 12.0", "current_limit = 15.0"))
    code, lines = run(bus, path, tmp_path / "r.json", capsys)
    assert code == 1
    assert defects(lines) == ["DEFECT limit outside the drive's: elbow_left: current_limit 15 A in the "
                              "description, the drive gives 12 A (0x2034:2)"]


def test_usage_errors_exit_2_before_the_bus(tmp_path, capsys):
    code = main(["commission", "--description", str(tmp_path / "none.toml"), "--bus-interface", "virtual",
                 "--bus-channel", "x"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "--description" in err[0]
    code = main(["commission", "--move", "tail", "--bus-interface", "virtual", "--bus-channel", "x"])
    assert code == 2 and "no such axis" in capsys.readouterr().err


def test_the_agent_serves_episodes_only_after_commissioning_passed(robot, tmp_path, capsys):
    from ersac_hil.agent.service import AgentConfig, AgentService
    from ersac_hil.zenoh_session import EmbeddedRouter
    from helpers.timing import PATIENT
    from protocol.zenoh import EpisodeRequest, ErrorReply, KeySpace
    bus, _ = robot
    record = tmp_path / "rec.json"
    keys = KeySpace("ubot-commission")

    def refusal() -> str | None:
        with EmbeddedRouter() as router:
            config = AgentConfig(robot=keys.robot, bus=bus, zenoh_connect=(router.endpoint,), timing=PATIENT,
                                 require_commissioning=True, commission_record=str(record))
            with AgentService(config) as agent, router.open_client() as session:
                if agent.uncommissioned is None:
                    return None
                assert agent.state().phase == "uncommissioned"
                request = EpisodeRequest("ep-gate", "bracing", (0.5,), 0).to_json()
                from helpers.waiting import wait_until
                wait_until(lambda: [r for r in session.liveliness().get(keys.agent_alive, timeout=1) if r.ok],
                           what="the agent")
                (reply,) = session.get(keys.episode_run, payload=request, timeout=30)
                error = ErrorReply.from_json(reply.err.payload.to_bytes())
                assert error.code == "unavailable" and error.reason == agent.uncommissioned
                return error.reason

    reason = refusal()
    assert reason.startswith("commissioning has not passed for robot description ubot5 on virtual:")
    assert f"no record at {record}" in reason and "run 'ersac-hil commission --description" in reason
    assert run(bus, "ubot5", record, capsys)[0] == 0
    assert refusal() is None
    record.write_text(record.read_text().replace('"fingerprint": "', '"fingerprint": "0'))  # another robot
    assert "does not match robot description ubot5" in refusal()


def test_move_needs_the_typed_axis_and_moves_only_that_axis_a_little(robot, tmp_path, capsys):
    import re
    bus, sim = robot
    record = tmp_path / "m.json"
    cycles = sim.stats.cycles
    code, lines = run(bus, "ubot5", record, capsys, "--move", "elbow_left", "--yes-move", "elbow")
    assert code == 1 and "not confirmed" in lines[-1] and "nothing moved" in lines[-1]
    assert sim.stats.cycles == cycles  # no SYNC
    code, lines = run(bus, "ubot5", record, capsys, "--move", "wheel_left", "--yes-move", "wheel_left")
    assert code == 1 and "torque axis" in lines[-1] and sim.stats.cycles == cycles
    code, lines = run(bus, "ubot5", record, capsys, "--move", "elbow_left", "--yes-move", "elbow_left")
    assert code == 0, lines
    moved = float(re.search(r"moved ([+-][0-9.]+) rad for ([+-][0-9.]+) asked", lines[-1]).group(1))
    asked = float(re.search(r"moved ([+-][0-9.]+) rad for ([+-][0-9.]+) asked", lines[-1]).group(2))
    assert abs(asked) == 0.05 and moved * asked > 0 and abs(moved) <= 2 * abs(asked)  # its way, a little
    assert sim.stats.cycles > cycles
    with sim.lock:
        arms = {axis: sim.sim.controller(board).status(axis).enabled
                for board in ("arm_left", "arm_right", "torso", "wheels") for axis in BOARDS[board]}
    assert not any(arms.values())  # disabled again at the end
