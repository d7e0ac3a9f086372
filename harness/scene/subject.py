"""The observed person: the nominal humanoid scaled (``SubjectSpec``), and a motion played by it.

The scaled subject performs the same joint angles. Its base position is the nominal one times ``scale`` (a
uniformly scaled person takes proportionally longer steps, and a uniformly scaled world keeps the soles on
the floor exactly); with jittered segments, the base height is then shifted per frame so that the body's
lowest point is where the uniformly scaled body's lowest point is (feet stay on the floor, a jump keeps its
clearance).
"""

from __future__ import annotations

import dataclasses

import numpy as np

from harness.body import BodyModel, geom_z_range
from harness.body.scaling import segment_factors
from harness.motion.motion import Motion
from harness.scene.spec import SubjectSpec


def subject_body(nominal: BodyModel, spec: SubjectSpec) -> BodyModel:
    """The observed humanoid of ``spec`` (``nominal`` itself when the spec is nominal)."""
    if spec.nominal:
        return nominal
    factors = segment_factors(nominal.body_names, spec.scale, spec.limb_scale, np.random.default_rng(spec.seed))
    return nominal.scaled(factors)


def observed_motion(motion: Motion, nominal: BodyModel, subject: BodyModel, scale: float) -> Motion:
    """``motion`` (a nominal performance) as the ``subject`` body (uniform part ``scale``) performs it."""
    if subject is nominal:
        return motion
    qpos = np.array(motion.qpos)
    qpos[:, :3] *= scale
    if not np.allclose(subject.segment_scale[1:], scale):
        target = scale * geom_z_range(nominal, motion.qpos)[:, :, 0].min(axis=1)
        lowest = geom_z_range(subject, qpos)[:, :, 0].min(axis=1)
        qpos[:, 2] += target - lowest
    return dataclasses.replace(motion, qpos=qpos)
