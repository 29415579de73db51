"""The agent's side of commissioning: on a physical bus it serves episodes only when the record
of a passed commissioning matches this description and the nodes it finds (``refusal``)."""
from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import canopen

from ersac_hil.commission.fingerprint import fingerprint, record_path, recorded
from ersac_hil.commission.scan import identities, sdo_client
from protocol.can.busconfig import BusConfig
from protocol.robot import RobotDescription


def refusal(description: RobotDescription, bus: BusConfig, network: canopen.Network,
            sdos: Mapping[int, canopen.sdo.SdoClient], record: str | Path | None = None,
            sdo_timeout_s: float = 0.3) -> str | None:
    """Why episodes must not run (``None``: commissioning passed for exactly this robot).

    ``sdos``: SDO clients the caller already has, by node-id (others are made on ``network``).
    """
    path = record_path(description, record)
    stored = recorded(path)
    how = (f"run 'ersac-hil commission --description {description.source or description.name} "
           f"--bus-interface {bus.interface} --bus-channel {bus.channel}'")
    if stored is None:
        return (f"commissioning has not passed for robot description {description.name} on "
                f"{bus.describe()} (no record at {path}): {how}")
    clients = []
    for dev in description.robot_devices:
        sdo = sdos.get(dev.node_id)
        if sdo is None:
            sdo = sdo_client(network, dev.node_id, None, sdo_timeout_s).sdo
        clients.append((dev.node_id, sdo))
    found = identities(clients)
    if fingerprint(description, found) != stored:
        return (f"commissioning record {path} does not match robot description {description.name} and the "
                f"{len(found)} node(s) answering on {bus.describe()} (the description or a drive changed): {how}")
    return None
