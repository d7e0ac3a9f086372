"""The humanoid56 body: loading, and the maps between joint names, qpos/qvel indices and angle vectors.

Layout of a configuration (``qpos``, 57 values): base position (3, metres, world frame), base orientation
(4, unit quaternion w, x, y, z, world from base), then the 50 hinge angles (radians) in model order.
Velocities (``qvel``, 56 values): base linear velocity (3, world frame), base angular velocity (3, base
frame, MuJoCo's convention for free joints), then the 50 angle rates.
"""

from __future__ import annotations

import sys
from functools import lru_cache
from pathlib import Path

import mujoco
import numpy as np

from harness.body.tree import KinematicTree
from harness.errors import ModelError, UnknownNameError

_CHECKOUT_MODEL = Path(__file__).resolve().parents[2] / "models" / "humanoid56.xml"
# A wheel (``pip install .``, not editable) puts the model beside the environment (pyproject.toml's data-files).
_INSTALLED_MODEL = Path(sys.prefix) / "share" / "monocular-motion-harness" / "models" / "humanoid56.xml"
DEFAULT_MODEL_PATH = _CHECKOUT_MODEL if _CHECKOUT_MODEL.is_file() else _INSTALLED_MODEL
#: The 50 hinges of humanoid56 in model order (``docs/humanoid56.md``); ``BodyModel.joint_names`` reads them
#: from the compiled model (tests check the two agree).
JOINT_NAMES: tuple[str, ...] = (
    "lowerback_y", "lowerback_x", "lowerback_z", "upperback_y", "upperback_x", "upperback_z",
    "thorax_y", "thorax_x", "thorax_z", "lowerneck_y", "lowerneck_x", "lowerneck_z",
    "upperneck_y", "upperneck_x", "upperneck_z", "head_y", "head_x", "head_z",
    "lclavicle_z", "lclavicle_x", "lhumerus_y", "lhumerus_x", "lhumerus_z", "lradius_y", "lwrist_z",
    "lhand_y", "lhand_x",
    "rclavicle_z", "rclavicle_x", "rhumerus_y", "rhumerus_x", "rhumerus_z", "rradius_y", "rwrist_z",
    "rhand_y", "rhand_x",
    "lfemur_y", "lfemur_x", "lfemur_z", "ltibia_y", "lfoot_y", "lfoot_x", "ltoes_y",
    "rfemur_y", "rfemur_x", "rfemur_z", "rtibia_y", "rfoot_y", "rfoot_x", "rtoes_y",
)
N_ANGLES = len(JOINT_NAMES)
# The mirror image through the body's sagittal (x-z) plane: left and right hinges swap, and every x
# (ab/adduction, side bend) and z (twist) angle changes sign; y (flexion) angles keep theirs. Exact because the
# model's two sides are mirror images (axes and ranges, tests/test_body_model.py).
_SIDED = ("clavicle", "humerus", "radius", "wrist", "hand", "femur", "tibia", "foot", "toes")
MIRROR_INDEX = np.array([JOINT_NAMES.index({"l": "r", "r": "l"}[n[0]] + n[1:] if n[1:].split("_")[0] in _SIDED
                                           else n) for n in JOINT_NAMES])
MIRROR_SIGN = np.array([-1.0 if n.endswith(("_x", "_z")) else 1.0 for n in JOINT_NAMES])
NQ = 7 + N_ANGLES
NV = 6 + N_ANGLES


def mirror_angles(angles: np.ndarray) -> np.ndarray:
    """Joint angles ``(..., 50)`` (any unit, model order) of the mirror-image pose (``MIRROR_INDEX``,
    ``MIRROR_SIGN``): the same pose performed with the other side."""
    return np.asarray(angles)[..., MIRROR_INDEX] * MIRROR_SIGN


def load_mjmodel(path: str | Path | None = None) -> mujoco.MjModel:
    """Compile a MuJoCo model file, with errors that name the file and the problem in one line."""
    path = Path(path) if path is not None else DEFAULT_MODEL_PATH
    if not path.is_file():
        raise ModelError(f"{path}: no such model file")
    try:
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as exc:
        first_line = str(exc).strip().splitlines()[0] if str(exc).strip() else "cannot be compiled"
        raise ModelError(f"{path}: {first_line}") from None


class BodyModel:
    """A compiled humanoid with one free joint at the root and 50 hinges, and its index maps.

    Holds one scratch ``MjData`` for kinematics (not safe to share between threads) and the kinematic tree as
    arrays (``tree``, for the compiled forward kinematics of ``harness.body.tree``). ``segment_scale``
    ``(nbody,)``: the length factor of each segment against the model file (ones for the nominal body; see
    ``harness.body.scaling`` and ``scaled``).
    """

    def __init__(self, model: mujoco.MjModel, path: Path | None = None, segment_scale: np.ndarray | None = None):
        self.model = model
        self.path = path
        self.segment_scale = np.ones(model.nbody) if segment_scale is None else np.asarray(segment_scale, float)
        self.data = mujoco.MjData(model)
        self._check_structure()
        self.tree = KinematicTree.of(model)
        hinge_ids = np.arange(1, model.njnt)
        self.joint_names: tuple[str, ...] = tuple(
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_JOINT, j) for j in hinge_ids
        )
        self.body_names: tuple[str, ...] = tuple(
            mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_BODY, b) for b in range(model.nbody)
        )
        self.angle_qpos_index = model.jnt_qposadr[hinge_ids].astype(int)
        self.angle_dof_index = model.jnt_dofadr[hinge_ids].astype(int)
        self.angle_body = model.jnt_bodyid[hinge_ids].astype(int)
        self.lower = model.jnt_range[hinge_ids, 0].copy()
        self.upper = model.jnt_range[hinge_ids, 1].copy()
        self.root_body = int(model.jnt_bodyid[0])
        # Geoms that belong to the humanoid (everything not attached to the world body).
        self.body_geoms = np.flatnonzero(model.geom_bodyid > 0)

    @classmethod
    def load(cls, path: str | Path | None = None) -> "BodyModel":
        path = Path(path) if path is not None else DEFAULT_MODEL_PATH
        return cls(load_mjmodel(path), path)

    @property
    def nominal(self) -> bool:
        """True for the model file's own proportions (no segment scaled)."""
        return bool(np.all(self.segment_scale == 1.0))

    def mjspec(self) -> mujoco.MjSpec:
        """A fresh ``MjSpec`` of this body (the model file, with this body's segment scaling applied), for
        building scenes around it."""
        from harness.body.scaling import scaled_mjspec

        path = self.path or DEFAULT_MODEL_PATH
        if self.nominal:
            return mujoco.MjSpec.from_file(str(path))
        return scaled_mjspec(path, self.body_names, self.segment_scale)

    def scaled(self, factors: np.ndarray) -> "BodyModel":
        """This model file with segment ``b`` scaled by ``factors[b]`` ``(nbody,)`` (relative to the file)."""
        from harness.body.scaling import scaled_mjspec

        factors = np.asarray(factors, dtype=float)
        if factors.shape != (self.model.nbody,) or not np.all(np.isfinite(factors) & (factors > 0)):
            raise ModelError(f"segment factors must be {self.model.nbody} positive numbers, got shape "
                             f"{factors.shape}")
        spec = scaled_mjspec(self.path or DEFAULT_MODEL_PATH, self.body_names, factors)
        return BodyModel(spec.compile(), self.path, factors)

    def _check_structure(self) -> None:
        m = self.model
        where = f"{self.path}: " if self.path else ""
        if m.njnt < 1 or m.jnt_type[0] != mujoco.mjtJoint.mjJNT_FREE:
            raise ModelError(f"{where}the first joint must be a free joint at the root body")
        hinges = m.jnt_type[1:] == mujoco.mjtJoint.mjJNT_HINGE
        if m.njnt - 1 != N_ANGLES or not np.all(hinges):
            raise ModelError(
                f"{where}expected 1 free joint and {N_ANGLES} hinges, found {m.njnt - 1} other joints "
                f"of which {int(hinges.sum())} hinges"
            )
        if m.nq != NQ or m.nv != NV:
            raise ModelError(f"{where}expected nq={NQ}, nv={NV}, found nq={m.nq}, nv={m.nv}")
        if not np.all(m.jnt_limited[1:]):
            unlimited = [mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_JOINT, j)
                         for j in np.flatnonzero(~m.jnt_limited.astype(bool))[1:] if j > 0]
            raise ModelError(f"{where}hinges without a range: {', '.join(unlimited)}")

    # --- name and index maps -------------------------------------------------------------------

    def angle_index(self, joint_name: str) -> int:
        """Position of a hinge in the 50-angle vector."""
        try:
            return self.joint_names.index(joint_name)
        except ValueError:
            raise UnknownNameError(f"unknown joint {joint_name!r}; joints are named <body>_<axis>, "
                           f"for example {self.joint_names[0]!r}") from None

    def body_id(self, body_name: str) -> int:
        bid = mujoco.mj_name2id(self.model, mujoco.mjtObj.mjOBJ_BODY, body_name)
        if bid < 0:
            raise UnknownNameError(f"unknown body {body_name!r}; bodies: {', '.join(self.body_names[1:])}")
        return int(bid)

    def angles(self, qpos: np.ndarray) -> np.ndarray:
        """The 50 hinge angles of configurations ``(..., 57) -> (..., 50)``, radians."""
        return np.asarray(qpos)[..., self.angle_qpos_index]

    def qpos(self, angles: np.ndarray, base_pos=None, base_quat=None) -> np.ndarray:
        """Assemble configurations from angles ``(..., 50)``; the base defaults to the model's zero pose."""
        angles = np.asarray(angles, dtype=float)
        out = np.broadcast_to(self.model.qpos0, angles.shape[:-1] + (NQ,)).copy()
        out[..., self.angle_qpos_index] = angles
        if base_pos is not None:
            out[..., 0:3] = base_pos
        if base_quat is not None:
            out[..., 3:7] = base_quat
        return out

    def zero_qpos(self) -> np.ndarray:
        """The standing reference pose (all angles zero, soles on the floor)."""
        return self.model.qpos0.copy()

    def clip_angles(self, angles: np.ndarray) -> np.ndarray:
        return np.clip(angles, self.lower, self.upper)

    def random_angles(self, rng: np.random.Generator, n: int | None = None, scale: float = 1.0) -> np.ndarray:
        """Angles drawn uniformly within ``scale`` times the joint ranges (around the range centre)."""
        shape = (N_ANGLES,) if n is None else (n, N_ANGLES)
        mid, half = 0.5 * (self.lower + self.upper), 0.5 * (self.upper - self.lower)
        return mid + scale * half * rng.uniform(-1.0, 1.0, size=shape)


@lru_cache(maxsize=1)
def nominal_body() -> BodyModel:
    """The model file's body, loaded once per process and shared (its scratch ``MjData`` makes it unsafe to
    share between threads, not between callers of one thread)."""
    return BodyModel.load()
