"""What a scenario (dm_control's "task") supplies: the props around the robot, the initial
state, the per-step test-bench actions (an impact, a grasp that can break) and ground truth.

Life cycle, driven by the Simulator:
- ``build_spec()`` once: the robot MJCF plus the scenario's props, compiled by the simulator;
- ``prepare(physics)`` once after compiling: computes the balanced initial state
  ``initial_qpos`` (``qpos0`` stays the model's reference configuration: MuJoCo measures
  hinge angles from it);
- ``vary(physics, load_rng)`` at every reset, before ``mj_resetData``: the episode's model
  edits (the lifting bottle's fill), from a random stream of their own;
- ``initialize_episode(physics, rng)`` at every reset, after ``mj_resetData``: sets the
  initial state and draws the episode's random quantities from ``rng`` (a generator spawned
  from the seed). Subclasses call ``super().initialize_episode``;
- ``before_step(physics)`` at every control period before the substeps;
- ``after_substep(physics)`` after every substep (only where needed: ``checks_substeps``);
  returns True when the scenario's failure (bottle dropped) happened in that substep.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import ClassVar

import mujoco
import numpy as np

from ..plant.physics import UBOT_XML, WHEEL_RADIUS, Physics


def robot_spec() -> mujoco.MjSpec:
    """A fresh, editable spec of the bare robot (ubot.xml)."""
    return mujoco.MjSpec.from_file(str(UBOT_XML))


def attach_props(spec: mujoco.MjSpec, xml_path: str, prefix: str) -> None:
    """Attach the MJCF file ``xml_path`` to the world of ``spec``; its element names get
    ``prefix`` (e.g. ``"bottle/"``)."""
    child = mujoco.MjSpec.from_file(xml_path)
    frame = spec.worldbody.add_frame()
    spec.attach(child, frame=frame, prefix=prefix)


def balanced_qpos(physics: Physics, pose: Mapping[str, float],
                  payload: tuple[int, ...] = (),
                  place_payload: Callable[[Physics], None] | None = None) -> np.ndarray:
    """Generalised positions with the robot standing on its wheels at x = y = 0, the joints
    at ``pose`` (axis -> rad) and the body pitched so that the combined centre of mass of the
    robot and the ``payload`` bodies is straight above the wheel axle (static balance).

    ``place_payload`` positions payload free bodies from the current kinematics (e.g. a
    bottle between the hands); it runs before and after the pitch is applied.
    """
    m, d = physics.model, physics.data
    mujoco.mj_resetData(m, d)
    for axis, q in pose.items():
        physics.set_joint_position(axis, q)
    root = m.jnt_qposadr[m.body_jntadr[physics.base_id]]
    d.qpos[root:root + 3] = (0.0, 0.0, WHEEL_RADIUS)
    d.qpos[root + 3:root + 7] = (1.0, 0.0, 0.0, 0.0)
    if place_payload is not None:
        mujoco.mj_kinematics(m, d)
        place_payload(physics)
    mujoco.mj_forward(m, d)
    com = physics.com((physics.base_id, *payload)) - d.xpos[physics.base_id]
    pitch = -math.atan2(com[0], com[2])
    d.qpos[root + 3:root + 7] = (math.cos(pitch / 2), 0.0, math.sin(pitch / 2), 0.0)

    def vertical_acc(z: float) -> float:
        d.qpos[root + 2] = z
        if place_payload is not None:
            mujoco.mj_kinematics(m, d)
            place_payload(physics)
        mujoco.mj_forward(m, d)
        return float(d.qacc[m.jnt_dofadr[m.body_jntadr[physics.base_id]] + 2])

    # sink the wheels into the (soft) floor until the contact carries the weight, so that the
    # episode starts in static equilibrium instead of a short drop
    lo, hi = WHEEL_RADIUS - 0.005, WHEEL_RADIUS
    for _ in range(40):
        mid = 0.5 * (lo + hi)
        if vertical_acc(mid) > 0.0:
            lo = mid
        else:
            hi = mid
    vertical_acc(0.5 * (lo + hi))
    return d.qpos.copy()


class Scenario:
    """Base scenario: the bare robot standing balanced in ``pose``."""

    name: ClassVar[str] = "idle"
    pose: ClassVar[Mapping[str, float]] = {
        "torso": 0.0, "shoulder_left": 0.0, "elbow_left": 1.2,
        "shoulder_right": 0.0, "elbow_right": 1.2,
    }
    checks_substeps: ClassVar[bool] = False

    def build_spec(self) -> mujoco.MjSpec:
        return robot_spec()

    def prepare(self, physics: Physics) -> None:
        self.initial_qpos = balanced_qpos(physics, self.pose)

    def vary(self, physics: Physics, rng: np.random.Generator) -> None:
        """Called at every reset before ``mj_resetData`` with the seed's load stream (a stream
        of its own, so the other draws of a seed do not depend on it): the episode's model
        edits (a payload's mass), none here."""

    def initialize_episode(self, physics: Physics, rng: np.random.Generator) -> None:
        """Called after ``mj_resetData``: the balanced initial state, at rest."""
        physics.data.qpos[:] = self.initial_qpos

    def before_step(self, physics: Physics) -> None:
        """Start of a control period."""

    def after_substep(self, physics: Physics) -> bool:
        return False

    # ---- ground truth (NaN where the scenario has no such thing) ----------------------------
    @property
    def impact_momentum(self) -> float:
        return math.nan

    @property
    def impact_time(self) -> float:
        return math.nan

    def trigger_impact(self, physics: Physics) -> None:
        raise RuntimeError(f"scenario {self.name!r} has no impact")

    @property
    def bottle_dropped(self) -> bool:
        return False

    def bottle_height(self, physics: Physics) -> float:
        return math.nan

    @property
    def liquid_mass(self) -> float:
        return math.nan

    def bottle_com(self, physics: Physics) -> np.ndarray:
        return np.full(3, math.nan)
