"""Typed errors of the robot-side agent.

Two families:

* ``AgentFault`` - the hardware side failed while the agent was talking to it (a node's
  heartbeat stopped, a SYNC cycle's TPDOs did not all arrive, the bus went away, a node never
  showed up). Each carries the ``EpisodeResult.status`` it turns into (``protocol.zenoh.STATUSES``).
* ``RequestRefused`` - the agent will not do what it was asked (a spline outside the joint
  limits, a configuration the controller refused): the episode never starts and the query
  gets a ``reply_err``.
"""
from __future__ import annotations


class AgentError(Exception):
    """Base of every error raised by ``ersac_hil.agent``."""


class AgentFault(AgentError):
    """The bus or a node failed. ``status`` is the episode status this fault ends with."""

    status = "fault_simulator"


class PdoTimeout(AgentFault):
    """Not every synchronous TPDO of a SYNC arrived before the deadline."""

    status = "fault_pdo_timeout"

    def __init__(self, cycle: int, missing: tuple[str, ...], deadline_s: float) -> None:
        self.cycle, self.missing, self.deadline_s = cycle, tuple(missing), deadline_s
        super().__init__(f"SYNC cycle {cycle}: no {', '.join(self.missing)} within "
                         f"{1000 * deadline_s:.0f} ms")


class HeartbeatLost(AgentFault):
    """A node's heartbeat is older than the consumer timeout (or it reported the agent's
    heartbeat lost by EMCY 0x8130)."""

    status = "fault_heartbeat"

    def __init__(self, device: str, age_s: float | None, timeout_s: float) -> None:
        self.device, self.age_s, self.timeout_s = device, age_s, timeout_s
        seen = "never heard" if age_s is None else f"silent for {1000 * age_s:.0f} ms"
        super().__init__(f"heartbeat of {device} lost: {seen} (timeout {1000 * timeout_s:.0f} ms)")


class NodeMissing(AgentFault):
    """Required nodes did not appear on the bus (no boot-up, no heartbeat)."""

    status = "fault_simulator"

    def __init__(self, devices: tuple[str, ...], waited_s: float) -> None:
        self.devices, self.waited_s = tuple(devices), waited_s
        super().__init__(f"no heartbeat from {', '.join(self.devices)} within {waited_s:.1f} s")


class BusDown(AgentFault):
    """The CAN bus itself failed (send error, the hub went away)."""

    status = "fault_simulator"


class BusFault(AgentFault):
    """A faulty node on the bus: frames that break the bus's contract (a TPDO of the wrong
    length or twice in a cycle, a foreign SYNC, error frames, ...); what it sent is never data."""

    status = "fault_simulator"


class SdoTimeout(AgentFault):
    """A node did not answer an SDO request."""

    status = "fault_simulator"


class EmcyFault(AgentFault):
    """An EMCY that is not a task outcome (e.g. a driver fault)."""

    status = "fault_emcy"


class DriveFault(AgentFault):
    """A CiA 402 drive did not take a mode of operation or a power state it was told to."""

    status = "fault_simulator"


class RequestRefused(AgentError):
    """The agent refuses a request before touching the robot. ``code`` is an
    ``protocol.zenoh.ERROR_CODES`` entry."""

    code = "invalid_request"


class LimitViolation(RequestRefused):
    """A policy would drive a joint outside its position or velocity limits."""


class ConfigRefused(RequestRefused):
    """A controller refused an SDO download (abort code, e.g. value range exceeded)."""

    code = "fault"

    def __init__(self, device: str, index: int, subindex: int, value: object, abort_code: int) -> None:
        self.device, self.index, self.subindex = device, index, subindex
        self.value, self.abort_code = value, abort_code
        super().__init__(f"{device} refused 0x{index:04X}:{subindex} = {value!r} "
                         f"(SDO abort 0x{abort_code:08X})")
