"""A CiA 402 bench for tests: the simulated ``ubot5-cia402`` robot (one drive per axis over the
plant) and a master network with python canopen's stock ``BaseNode402`` per drive, the agent's
heartbeat, and lock-step cycles (the drive's cyclic RPDO, SYNC, its TPDOs)."""
from __future__ import annotations

from canopen.profiles.p402 import BaseNode402

from ersac_hil.canbus.heartbeat import HeartbeatProducer
from firmware_sim.nodes.simrobot import SimulatedRobot
from helpers.can_nodes import FrameLog, set_state
from helpers.timing import PATIENCE_S, patient_controllers, patient_sdo
from protocol.can import cobid
from protocol.can.busconfig import open_network
from protocol.can.cia402 import DriveScaling
from protocol.can.devices import object_dictionary
from protocol.robot import load_description

DESCRIPTION = load_description("ubot5-cia402")
DRIVES = tuple(d for d in DESCRIPTION.devices if d.profile == "cia402")
CSP, CST = "CYCLIC SYNCHRONOUS POSITION", "CYCLIC SYNCHRONOUS TORQUE"


class Bench:
    """The simulated robot, a master network with a ``BaseNode402`` per drive and the agent's
    heartbeat."""

    def __init__(self, bus_config) -> None:
        self.robot = SimulatedRobot(bus_config, description=DESCRIPTION)
        self.network = open_network(bus_config)
        self.nodes: dict[str, BaseNode402] = {}
        for d in DRIVES:
            node = BaseNode402(d.node_id, object_dictionary(d))
            # patient timing (a loaded machine), the master's logic unchanged
            node.TIMEOUT_SWITCH_STATE_SINGLE = node.TIMEOUT_SWITCH_STATE_FINAL = PATIENCE_S
            node.TIMEOUT_SWITCH_OP_MODE = node.TIMEOUT_CHECK_TPDO = node.TIMEOUT_RESET_FAULT = PATIENCE_S
            self.network.add_node(node)
            self.nodes[d.name] = node
        patient_sdo(self.nodes.values())
        patient_controllers(self.nodes.values())  # a late heartbeat is not what these tests test
        self.heartbeat = HeartbeatProducer(self.network).start()
        self.tpdos = FrameLog(self.network, [cobid.tpdo(3, d.node_id) for d in DRIVES])

    def start(self, *names: str) -> list[BaseNode402]:
        """NMT pre-operational, ``setup_402_state_machine``, NMT operational."""
        set_state(self.network, DRIVES, "PRE-OPERATIONAL")
        nodes = [self.nodes[n] for n in names]
        for node in nodes:
            node.setup_402_state_machine()
        set_state(self.network, DRIVES, "OPERATIONAL")
        return nodes

    def cycle(self, node: BaseNode402, n: int = 1) -> None:
        """``n`` lock-step cycles: the node's cyclic RPDO, SYNC, then its last TPDO of the SYNC."""
        cob = cobid.tpdo(3, node.id)
        for _ in range(n):
            seen = self.tpdos.count(cob)
            node.rpdo[2].transmit()
            self.network.sync.transmit()
            self.tpdos.wait_for(lambda frames, k=seen + 1: sum(1 for c, _ in frames if c == cob) >= k,
                                what=f"TPDO3 of node {node.id:#x}")

    def close(self) -> None:
        self.heartbeat.stop()
        self.tpdos.close()
        self.network.disconnect()
        self.robot.close()


def scaling(name: str) -> DriveScaling:
    axis = DESCRIPTION.axis(name)
    return DriveScaling(axis.gear, axis.encoder_counts, axis.current_limit, axis.torque_constant * axis.current_limit)
