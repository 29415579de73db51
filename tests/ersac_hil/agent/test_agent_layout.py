"""The uBot's layout on a robot's nodes comes from its robot description (``agent.layout``): the
joints, commands, status words and arm boards follow the description's nodes, never tables in
code; a board robot whose arm boards have other node-ids runs the very same episode."""
from __future__ import annotations

import uuid
from dataclasses import replace

import pytest

from ersac_hil.agent.cia402 import agent_bus
from ersac_hil.agent.episode import EpisodeRunner
from ersac_hil.agent.layout import JOINTS, STATUS_PARTS, RobotLayout
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.timing import PATIENCE_S, PATIENT, patient_controllers, patient_sdo
from protocol.can.busconfig import BusConfig
from protocol.robot import default_description, load_description
from protocol.robot.load import SHIPPED_DIR
from protocol.zenoh import EpisodeRequest

pytestmark = pytest.mark.timeout(300)


def test_the_board_robot_layout():
    layout = RobotLayout.of(default_description())
    assert [d.name for d in layout.cyclic] == ["wheels", "torso", "arm_left", "arm_right", "imu"]
    assert layout.joint_index == {("wheels", 1): 0, ("wheels", 2): 1, ("torso", 1): 2, ("arm_left", 1): 3,
                                  ("arm_left", 2): 4, ("arm_right", 1): 5, ("arm_right", 2): 6}
    assert layout.arm("right").node_id == 0x13
    assert layout.status_nodes == (("wheels",), ("torso",), ("arm_left",), ("arm_right",), ("imu",))


def test_the_cia402_robot_layout():
    layout = RobotLayout.of(load_description("ubot5-cia402"))
    assert [(d.name, d.node_id) for d in layout.actuated] == [(j, 0x21 + k) for k, j in enumerate(JOINTS)]
    assert layout.joint_index == {(j, 1): k for k, j in enumerate(JOINTS)}
    assert dict(zip(STATUS_PARTS, layout.status_nodes))["arm_left"] == ("shoulder_left", "elbow_left")
    with pytest.raises(ValueError, match="arm_left of this robot are on 2 nodes"):
        layout.arm("left")  # no arm board to download a spline to: the host streams it


def test_a_description_without_a_joint_the_agent_needs_is_refused_naming_it():
    board = default_description()
    no_elbow = replace(board, axes=tuple(a for a in board.axes if a.name != "elbow_right"))
    with pytest.raises(ValueError, match="joint elbow_right is on 0 nodes"):
        RobotLayout.of(no_elbow)


def test_the_agent_refuses_a_description_without_a_joint_in_one_line(tmp_path, capsys):
    from ersac_hil.cli import main
    text = (SHIPPED_DIR / "ubot5.toml").read_text()
    start = text.index("[axes.elbow_right]")
    path = tmp_path / "no_elbow.toml"
    path.write_text(text[:start] + text[text.index("\n[", start) + 1:])
    assert "elbow_right" not in load_description(path).joints  # a description the loader takes
    code = main(["agent", "--robot", "r", "--zenoh", "tcp/127.0.0.1:9", "--bus-interface", "virtual",
                 "--bus-channel", "x", "--description", str(path)])
    err = [line for line in capsys.readouterr().err.splitlines() if line.strip()]
    assert code == 2 and len(err) == 1 and "elbow_right" in err[0], err  # nothing started


def _lift(description) -> tuple:
    config = BusConfig("virtual", f"test-{uuid.uuid4().hex[:8]}")
    with SimulatedRobot(config, description=description):
        bus = agent_bus(config, description, PATIENT).open()
        try:
            bus.wait_for_nodes(timeout_s=PATIENCE_S)
            patient_sdo(bus.nodes.values())
            patient_controllers(bus.nodes.values())
            runner = EpisodeRunner(bus)
            r = runner.run(runner.plan(EpisodeRequest("lift", "lifting", (1.2, 1.4, 2.2, 0.9, 1.2, 1.2, 1.2), 3)))
            return r, bus.layout
        finally:
            bus.close()


def test_arm_boards_on_other_node_ids_run_the_same_episode(tmp_path):
    """The arm boards' node-ids swapped in the description: the agent sends each arm's
    commands to the node the description names and reads each joint from it (the lifting
    arms reach the goal), and the episode is the default robot's to the bit."""
    text = (SHIPPED_DIR / "ubot5.toml").read_text()
    left, right = "[nodes.arm_left]\nnode_id = 0x12", "[nodes.arm_right]\nnode_id = 0x13"
    assert left in text and right in text
    path = tmp_path / "swapped.toml"
    path.write_text(text.replace(left, "[nodes.arm_left]\nnode_id = 0x13").replace(right, "[nodes.arm_right]\nnode_id = 0x12"))
    swapped = load_description(path)
    assert swapped.device("arm_left").node_id == 0x13
    result, layout = _lift(swapped)
    assert layout.arm("left").node_id == 0x13 and layout.joint_index[("arm_left", 2)] == JOINTS.index("elbow_left")
    assert result.status == "ok" and result.detail.startswith("goal reached"), result.detail
    reference, _ = _lift(default_description())
    assert result.cost_terms == reference.cost_terms and result.failures == reference.failures
