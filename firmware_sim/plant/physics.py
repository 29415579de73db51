"""MuJoCo physics of the uBot with named accessors (dm_control's ``Physics`` idea, minus the
framework): the robot's seven actuated axes are addressed by name, never by raw index.

Stepping follows MuJoCo's two-phase pattern so that a control period ends with fresh
positions and velocities::

    physics.forward()                 # once after a reset
    for each substep:
        write controls                # firmware, see controllers/firmware.py
        physics.dynamics()            # mj_step2: forces at t_k, integrate to t_k+1
        read forces                   # actuator forces/constraint forces applied during the substep
        physics.kinematics()          # mj_step1: positions/velocities/gyro at t_k+1

``data.actuator_force`` and acceleration-stage sensors therefore describe the last substep
(state t_k), positions, velocities and the gyro describe t_k+1.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from pathlib import Path

import mujoco
import numpy as np

UBOT_XML = Path(__file__).with_name("ubot.xml")

AXES: tuple[str, ...] = (
    "wheel_left", "wheel_right", "torso",
    "shoulder_left", "elbow_left", "shoulder_right", "elbow_right",
)
"""Actuated axes in canonical order (joint name = actuator name = axis name)."""
WHEEL_AXES: tuple[str, ...] = AXES[:2]
IMPEDANCE_AXES: tuple[str, ...] = AXES[2:]
WHEEL_RADIUS = 0.10
"""m, radius of the wheel geoms in ubot.xml."""

ROBOT_ROOT = "base"
FLOOR = "floor"


class UnknownNameError(KeyError):
    """A body/joint/axis/site name that the model does not contain."""


@dataclass(frozen=True)
class AxisIndex:
    """Index arrays of the seven axes into MuJoCo's arrays, all shape (7,), order ``AXES``.

    Attributes:
        qpos: address of each joint in ``qpos``; dof: address in ``qvel``/``qacc``.
        actuator: actuator id; ctrl: address of the actuator's first control input
            (``ff`` for wheels, ``pos`` for impedance axes; ``vel`` follows at ``ctrl + 1``).
    """

    qpos: np.ndarray
    dof: np.ndarray
    actuator: np.ndarray
    ctrl: np.ndarray

    @functools.cached_property
    def qpos_view(self) -> slice | np.ndarray:
        """``qpos`` as a slice where the addresses are contiguous (indexing gives a view)."""
        return as_slice(self.qpos)

    @functools.cached_property
    def dof_view(self) -> slice | np.ndarray:
        """``dof`` as a slice where the addresses are contiguous (indexing gives a view)."""
        return as_slice(self.dof)

    @functools.cached_property
    def actuator_view(self) -> slice | np.ndarray:
        """``actuator`` as a slice where the ids are contiguous (indexing gives a view)."""
        return as_slice(self.actuator)

    @classmethod
    def from_model(cls, model: mujoco.MjModel) -> "AxisIndex":
        qpos, dof, act, ctrl = [], [], [], []
        for name in AXES:
            jid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, name)
            aid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_ACTUATOR, name)
            if jid < 0 or aid < 0:
                raise UnknownNameError(f"model lacks joint/actuator {name!r}")
            qpos.append(model.jnt_qposadr[jid])
            dof.append(model.jnt_dofadr[jid])
            act.append(aid)
            ctrl.append(model.actuator_ctrladr[aid])
        return cls(*(np.asarray(a, dtype=np.intp) for a in (qpos, dof, act, ctrl)))


def as_slice(index: np.ndarray) -> slice | np.ndarray:
    """``index`` (shape (n,)) as the slice it spans when its entries are consecutive and
    ascending (indexing with it selects the same elements, as a view), else ``index`` itself."""
    start = int(index[0]) if len(index) else 0
    if len(index) and np.array_equal(index, np.arange(start, start + len(index))):
        return slice(start, start + len(index))
    return index


class Physics:
    """One compiled model and its data, with named accessors.

    Create with :meth:`from_xml_path` (the bare robot) or :meth:`from_spec` (robot plus a
    scenario's props). ``model`` may be edited at run time by the firmware (gains, force
    ranges) and the scenarios (equality activation, geom collision bits); each editor restores
    its own fields on reset.
    """

    def __init__(self, model: mujoco.MjModel) -> None:
        self.model = model
        self.data = mujoco.MjData(model)
        self.axes = AxisIndex.from_model(model)
        self.base_id = self.body_id(ROBOT_ROOT)
        self.imu_site_id = self.site_id("imu")
        self.floor_geom_id = self.geom_id(FLOOR)

    # ---- construction ---------------------------------------------------------------------
    @classmethod
    def from_xml_path(cls, path: str | Path = UBOT_XML) -> "Physics":
        return cls(mujoco.MjModel.from_xml_path(str(path)))

    @classmethod
    def from_spec(cls, spec: mujoco.MjSpec) -> "Physics":
        return cls(spec.compile())

    # ---- stepping -------------------------------------------------------------------------
    @property
    def timestep(self) -> float:
        return float(self.model.opt.timestep)

    @property
    def time(self) -> float:
        return float(self.data.time)

    def reset(self) -> None:
        """``mj_resetData``: qpos0, zero velocity/controls/time, equality activation from
        ``eq_active0``."""
        mujoco.mj_resetData(self.model, self.data)

    def forward(self) -> None:
        mujoco.mj_forward(self.model, self.data)

    def kinematics(self) -> None:
        """Position and velocity stages at the current state (``mj_step1``)."""
        mujoco.mj_step1(self.model, self.data)

    def dynamics(self) -> None:
        """Forces with the current controls, then integrate one timestep (``mj_step2``)."""
        mujoco.mj_step2(self.model, self.data)

    # ---- names ----------------------------------------------------------------------------
    def _id(self, kind: mujoco.mjtObj, name: str) -> int:
        i = mujoco.mj_name2id(self.model, kind, name)
        if i < 0:
            raise UnknownNameError(f"no {kind.name[6:].lower()} named {name!r}")
        return i

    def body_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_BODY, name)

    def joint_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_JOINT, name)

    def geom_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_GEOM, name)

    def site_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_SITE, name)

    def equality_id(self, name: str) -> int:
        return self._id(mujoco.mjtObj.mjOBJ_EQUALITY, name)

    def axis_number(self, axis: str) -> int:
        """Position of ``axis`` in ``AXES``."""
        try:
            return AXES.index(axis)
        except ValueError:
            raise UnknownNameError(f"unknown axis {axis!r}; axes are {AXES}") from None

    # ---- named state ----------------------------------------------------------------------
    def set_joint_position(self, axis: str, value: float) -> None:
        self.data.qpos[self.axes.qpos[self.axis_number(axis)]] = value

    def joint_range(self, axis: str) -> tuple[float, float]:
        """Mechanical range (rad); (-inf, inf) for unlimited joints (wheels)."""
        jid = self.joint_id(axis)
        if not self.model.jnt_limited[jid]:
            return (-math.inf, math.inf)
        lo, hi = self.model.jnt_range[jid]
        return (float(lo), float(hi))

    def body_pitch(self) -> float:
        """Pitch of the lower body (rad, positive = leaning forward), from the IMU site frame."""
        r = self.data.site_xmat[self.imu_site_id]
        return math.atan2(-r[6], r[8])

    def base_position(self) -> np.ndarray:
        """World position of the wheel axle centre, shape (3,)."""
        return self.data.xpos[self.base_id].copy()

    def robot_mass(self) -> float:
        return float(self.model.body_subtreemass[self.base_id])

    def com(self, body_ids: tuple[int, ...]) -> np.ndarray:
        """Combined centre of mass of the subtrees rooted at ``body_ids``, shape (3,)."""
        masses = self.model.body_subtreemass[list(body_ids)]
        coms = self.data.subtree_com[list(body_ids)]
        return (masses[:, None] * coms).sum(axis=0) / masses.sum()

    def geom_mask(self, names: tuple[str, ...]) -> np.ndarray:
        """Boolean mask over all geoms, True for ``names``, shape (ngeom,)."""
        mask = np.zeros(self.model.ngeom, dtype=bool)
        mask[[self.geom_id(n) for n in names]] = True
        return mask

    def contacts_with_floor(self, geoms: np.ndarray | frozenset[int]) -> bool:
        """True when a geom selected by ``geoms`` touches the floor now. ``geoms`` is a mask
        from :meth:`geom_mask` (shape (ngeom,)), an array of geom ids or a frozenset of geom
        ids (the cheapest: checked once per control period by the fall detector)."""
        if self.data.ncon == 0:
            return False
        if not isinstance(geoms, frozenset):
            geoms = frozenset((np.flatnonzero(geoms) if geoms.dtype == bool else geoms).tolist())
        floor = self.floor_geom_id
        # a few contacts a period: a loop over the pairs is cheaper than array masks
        for g1, g2 in self.data.contact.geom.tolist():
            if (g1 == floor and g2 in geoms) or (g2 == floor and g1 in geoms):
                return True
        return False
