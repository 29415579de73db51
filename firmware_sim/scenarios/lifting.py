"""Dynamic heavy lifting: a 1 kg partially filled bottle lifted from near the ground to about
1.2 m by an arm spline.

- The bottle (bottle.xml: rigid shell + hidden sloshing mass) is held between the hands by
  two weld constraints (forearm_left <-> bottle, forearm_right <-> bottle), a rigid grasp
  whose relative poses are those of the initial state. It collides with the floor only.
- Initial state: arms down-forward with the bottle centre at ~0.16 m (its bottom 5 cm above
  the floor), body pitched so that robot + bottle are statically balanced.
- Grasp failure: after every substep the translational force in each weld is compared with
  the episode's grip limit; above it the grasp breaks (both welds released, the bottle falls):
  ``bottle_dropped``. A violent trajectory (large hand accelerations) drops the bottle.
- Torque-limited shoulders (the paper: "most arm trajectories fail (arm torque limits)"). On
  this bench the shoulder drivers' hardware current limit is ``shoulder_current_limit``
  (2.0 A: 8.3 N m at the joint instead of the 12 A / 49.7 N m of the bracing bench), and the
  shoulder gear trains have Coulomb friction ``shoulder_friction`` (1.0 N m). Holding the
  bottle with the arms near the horizontal needs ~7.5-8.5 N m per shoulder, so a slow,
  quasi-static lift stalls near shoulder height, and only a swing that carries the bottle
  through the horizontal with momentum gets it over (dynamic lifting). The friction holds a
  stalled arm where it stopped (a current-limited motor gives no damping: without it a failed
  swing rocks between 0.4 and 1.2 rad for the whole episode and can hit the floor with the
  bottle), so a failed lift's height error is graded by how high the swing got.
- Random per episode: the grip limit (the scenario stream) and the liquid fill (the load
  stream, see ``vary``). The bottle sits loosely in simple claws, so how firmly it is held
  varies from trial to trial: normal around ``grasp_force_limit`` with relative spread
  ``grip_spread``, kept within +-2.5 spreads. The bottle is partially filled and the fill
  varies between trials: the liquid's mass is normal around bottle.xml's 0.6 kg with
  relative spread ``fill_spread``, within +-2.5 spreads (0.45-0.75 kg), which moves the
  torque a lift needs by a few percent: a lift near the stall edge succeeds only part of the
  time, and how often changes smoothly with its timing.
- Ground truth: the bottle's height (origin = shell centre), the centre of mass of shell +
  liquid, which moves with the slosh, and the liquid's mass.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar

import mujoco
import numpy as np

from ..plant.physics import Physics
from .base import Scenario, attach_props, balanced_qpos, robot_spec

BOTTLE_XML = Path(__file__).with_name("bottle.xml")
SHOULDERS = ("shoulder_left", "shoulder_right")
GRASPS = (("grasp_left", "forearm_left"), ("grasp_right", "forearm_right"))


def fill_factor(rng: np.random.Generator, spread: float) -> float:
    """One episode's liquid mass relative to nominal: 1 + spread z, z standard normal within
    +-2.5."""
    return 1.0 + spread * float(np.clip(rng.standard_normal(), -2.5, 2.5))


class Lifting(Scenario):
    name: ClassVar[str] = "lifting"
    pose: ClassVar[dict[str, float]] = {
        "torso": 0.0, "shoulder_left": 0.0, "elbow_left": 0.95,
        "shoulder_right": 0.0, "elbow_right": 0.95,
    }
    checks_substeps: ClassVar[bool] = True
    grasp_force_limit = 25.0
    """N per hand, nominal grip limit (about 5x the static share of the bottle's weight; a
    smooth 3 s lift peaks near 10 N)."""
    grip_spread = 0.08
    """Relative standard deviation of the grip limit between episodes."""
    shoulder_current_limit = 2.0
    """A, hardware current limit of the shoulder drivers on this bench (module docstring)."""
    shoulder_friction = 1.0
    """N m, Coulomb friction of each shoulder's gear train (module docstring)."""
    fill_spread = 0.1
    """Relative standard deviation of the liquid's mass (bottle.xml: 0.6 kg) between episodes."""

    def build_spec(self) -> mujoco.MjSpec:
        spec = robot_spec()
        attach_props(spec, str(BOTTLE_XML), "bottle/")
        for name, hand in GRASPS:
            eq = spec.add_equality(name=name, type=mujoco.mjtEq.mjEQ_WELD,
                                   objtype=mujoco.mjtObj.mjOBJ_BODY, name1=hand, name2="bottle/shell")
            eq.solref = [0.005, 1.0]
            eq.active = False  # switched on in prepare(), once the relative poses are set
        for name in SHOULDERS:
            act = spec.actuator(name)
            torque = float(act.gainprm[1]) * self.shoulder_current_limit
            act.forcerange = [-torque, torque]
            spec.joint(name).frictionloss = self.shoulder_friction
        return spec

    def prepare(self, physics: Physics) -> None:
        self._bottle = physics.body_id("bottle/shell")
        self._liquid = physics.body_id("bottle/liquid")
        self._liquid_mass0 = float(physics.model.body_mass[self._liquid])
        self._liquid_inertia0 = physics.model.body_inertia[self._liquid].copy()
        self._liquid_mass = self._liquid_mass0
        m = physics.model
        jid = m.body_jntadr[self._bottle]
        self._bottle_q = int(m.jnt_qposadr[jid])
        self._hands = [physics.site_id("hand_left"), physics.site_id("hand_right")]
        self._eqs = np.array([physics.equality_id(name) for name, _ in GRASPS])
        self.grip_limit = self.grasp_force_limit
        place = dict(payload=(self._bottle,), place_payload=self._place_bottle)
        balanced_qpos(physics, self.pose, **place)       # grasps off: find the pose
        self._set_grasp_poses(physics)
        m.eq_active0[self._eqs] = True                    # grasps on: let the wheels carry
        self.initial_qpos = balanced_qpos(physics, self.pose, **place)  # the bottle too
        self._dropped = False

    def _set_grasp_poses(self, physics: Physics) -> None:
        """Weld data = the bottle's pose relative to each forearm in the initial state
        (``balanced_qpos`` left the data there). eq_data: anchor in body2 (3), position of the
        anchor in body1 (3), orientation of body2 in body1 (4), torque scale, flag."""
        m, d = physics.model, physics.data
        for eq, (_, hand) in zip(self._eqs, GRASPS):
            b1 = physics.body_id(hand)
            rot1 = d.xmat[b1].reshape(3, 3)
            inv1 = np.zeros(4)
            mujoco.mju_negQuat(inv1, d.xquat[b1])
            rel = np.zeros(4)
            mujoco.mju_mulQuat(rel, inv1, d.xquat[self._bottle])
            m.eq_data[eq, 0:3] = 0.0
            m.eq_data[eq, 3:6] = rot1.T @ (d.xpos[self._bottle] - d.xpos[b1])
            m.eq_data[eq, 6:10] = rel
            m.eq_data[eq, 10] = 1.0
            m.eq_data[eq, 11] = 0.0

    def _place_bottle(self, physics: Physics) -> None:
        d = physics.data
        centre = d.site_xpos[self._hands].mean(axis=0)
        d.qpos[self._bottle_q:self._bottle_q + 3] = centre
        d.qpos[self._bottle_q + 3:self._bottle_q + 7] = (1.0, 0.0, 0.0, 0.0)

    def vary(self, physics: Physics, rng: np.random.Generator) -> None:
        """The episode's liquid fill from the load stream (its own stream of the seed, so the
        grip limit and every other draw are unchanged): mass and inertia of the hidden liquid
        scaled by ``fill_factor``, the model's derived constants recomputed."""
        m = physics.model
        scale = fill_factor(rng, self.fill_spread)
        m.body_mass[self._liquid] = self._liquid_mass0 * scale
        m.body_inertia[self._liquid] = self._liquid_inertia0 * scale
        self._liquid_mass = float(m.body_mass[self._liquid])
        mujoco.mj_setConst(m, physics.data)

    def initialize_episode(self, physics: Physics, rng: np.random.Generator) -> None:
        super().initialize_episode(physics, rng)
        z = np.clip(rng.standard_normal(), -2.5, 2.5)
        self.grip_limit = self.grasp_force_limit * (1.0 + self.grip_spread * float(z))
        physics.data.eq_active[self._eqs] = True
        self._dropped = False
        self.peak_grasp_force = 0.0

    def after_substep(self, physics: Physics) -> bool:
        if self._dropped:
            return False
        d = physics.data
        ne = d.ne
        if ne != 12:  # both welds active: 2 x (3 translational + 3 rotational) rows
            return False
        f = d.efc_force[:12].tolist()    # equality rows come first: left weld, right weld
        force = max(math.hypot(f[0], f[1], f[2]), math.hypot(f[6], f[7], f[8]))
        if force > self.peak_grasp_force:
            self.peak_grasp_force = force
        if force <= self.grip_limit:
            return False
        d.eq_active[self._eqs] = False
        self._dropped = True
        return True

    @property
    def bottle_dropped(self) -> bool:
        return self._dropped

    @property
    def liquid_mass(self) -> float:
        return self._liquid_mass

    def bottle_height(self, physics: Physics) -> float:
        return float(physics.data.xpos[self._bottle][2])

    def bottle_com(self, physics: Physics) -> np.ndarray:
        return physics.data.subtree_com[self._bottle].copy()
