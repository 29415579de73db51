"""Bracing for a fall: a 3.3 kg pendulum bob strikes the balancing robot in the back.

- Initial state: standing balanced (COM over the axle) with the arms in the bracing pose
  (the firmware holds the current pose at reset; the agent sets stiffness and setpoints).
- Impact momentum p ~ N(14, 2^2) N s from the seed, clipped to [6, 22] (4 sigma), recorded.
- At ``impact_time`` (0.25 s after reset) or on :meth:`trigger_impact`, whichever comes first,
  the test bench places the pendulum so that its bob, at the bottom of its swing, touches the
  torso's back at 0.50 m height, and launches it from ``launch_angle`` behind with the speed
  that gives |p| = m v exactly at the bottom.
- Wheel chocks (5 cm blocks 3 mm in front of both wheels, pendulum.xml) keep the robot from
  rolling forward out of the fall: with free wheels a balance controller that lets the robot
  roll away can catch a 14 N s strike (the wheeled pendulum's capture region is large); with
  the chocks only the wheels' reaction torque can pitch the body back, which is far too
  little, so the robot falls forward onto its arms whatever the wheels do (checked with LQR
  gains over a grid of weights, up to the 10 A wheel current limit).
- 0.15 s after the launch the test bench catches the pendulum (its collisions are switched off),
  so it strikes once.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import ClassVar

import mujoco
import numpy as np

from ..plant.physics import Physics
from .base import Scenario, attach_props, robot_spec

PENDULUM_XML = Path(__file__).with_name("pendulum.xml")


class Bracing(Scenario):
    name: ClassVar[str] = "bracing"
    pose: ClassVar[dict[str, float]] = {
        "torso": 0.0, "shoulder_left": 0.5, "elbow_left": 0.75,
        "shoulder_right": 0.5, "elbow_right": 0.75,
    }
    momentum_mean = 14.0
    """N s."""
    momentum_std = 2.0
    momentum_clip = (6.0, 22.0)
    impact_delay = 0.25
    """s after reset at which the pendulum is launched automatically."""
    launch_angle = 0.06
    """rad behind the bottom of the swing (6 cm of travel, ~14 ms before contact)."""
    catch_delay = 0.15
    """s after the launch at which the pendulum's collisions are switched off."""

    def build_spec(self) -> mujoco.MjSpec:
        spec = robot_spec()
        attach_props(spec, str(PENDULUM_XML), "pendulum/")
        return spec

    def prepare(self, physics: Physics) -> None:
        super().prepare(physics)
        m = physics.model
        self._bob = physics.geom_id("pendulum/bob")
        self._bob_bits = (int(m.geom_contype[self._bob]), int(m.geom_conaffinity[self._bob]))
        self._mocap = int(m.body_mocapid[physics.body_id("pendulum/pivot")])
        jid = physics.joint_id("pendulum/hinge")
        self._qadr, self._dadr = int(m.jnt_qposadr[jid]), int(m.jnt_dofadr[jid])
        self._impact_site = physics.site_id("impact")
        self._bob_mass = float(m.body_mass[physics.body_id("pendulum/arm")])
        self._bob_radius = float(m.geom_size[self._bob][0])
        self._length = float(-m.geom_pos[self._bob][2])

    def initialize_episode(self, physics: Physics, rng: np.random.Generator) -> None:
        super().initialize_episode(physics, rng)
        m = physics.model
        m.geom_contype[self._bob], m.geom_conaffinity[self._bob] = self._bob_bits
        p = rng.normal(self.momentum_mean, self.momentum_std)
        self._momentum = float(np.clip(p, *self.momentum_clip))
        self._launch_time = math.nan
        self._caught = False

    @property
    def impact_momentum(self) -> float:
        return self._momentum

    @property
    def impact_time(self) -> float:
        """Sim time of the launch (NaN before)."""
        return self._launch_time

    def before_step(self, physics: Physics) -> None:
        t = physics.time
        if math.isnan(self._launch_time):
            if t >= self.impact_delay - 1e-9:
                self.trigger_impact(physics)
        elif not self._caught and t >= self._launch_time + self.catch_delay - 1e-9:
            physics.model.geom_contype[self._bob] = 0
            physics.model.geom_conaffinity[self._bob] = 0
            self._caught = True

    def trigger_impact(self, physics: Physics) -> None:
        """Launch the pendulum now (once per episode; later calls do nothing)."""
        if not math.isnan(self._launch_time):
            return
        d = physics.data
        g = -float(physics.model.opt.gravity[2])
        L, phi = self._length, self.launch_angle
        site = d.site_xpos[self._impact_site]
        bottom = np.array([site[0] - self._bob_radius, site[1], site[2]])
        d.mocap_pos[self._mocap] = bottom + (0.0, 0.0, L)
        v = self._momentum / self._bob_mass
        d.qpos[self._qadr] = -phi
        d.qvel[self._dadr] = math.sqrt(v * v - 2.0 * g * L * (1.0 - math.cos(phi))) / L
        physics.kinematics()
        self._launch_time = physics.time
