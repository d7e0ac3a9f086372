"""Scaled copies of the humanoid: the observed subject when it does not match the engine's nominal body.

A *segment* is a body with its geoms: it spans from its own origin (its joint) to the origins of its
children. Segment ``b`` scaled by ``f_b`` means every length in ``b``'s frame is multiplied by ``f_b``: its
geoms' positions, end points and sizes (radii included), its sites, and the offsets of its child bodies
(which are the segment's lengths). So each segment of the scaled body is a uniformly scaled copy of the
nominal one, and a surface point of the nominal segment maps one-to-one to ``f_b`` times its body-frame
coordinates on the scaled segment. Joint axes and ranges are unchanged: the same ``qpos`` poses both bodies.
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np

LIMB_CLIP_STD = 3.0      # segment factors are 1 + std * z with z clipped to +-3


def pair_name(body_name: str, names: tuple[str, ...]) -> str:
    """The name shared by a left/right pair (``lfemur``, ``rfemur`` -> ``femur``); other bodies keep theirs."""
    if body_name[:1] in ("l", "r"):
        other = ("r" if body_name[0] == "l" else "l") + body_name[1:]
        if other in names:
            return body_name[1:]
    return body_name


def segment_factors(body_names: tuple[str, ...], scale: float, limb_std: float, rng: np.random.Generator
                    ) -> np.ndarray:
    """Length factor per body ``(nbody,)`` (index 0, the world, is 1): ``scale * (1 + limb_std * z)``.

    One standard normal ``z`` (clipped at ``LIMB_CLIP_STD``) per segment, shared by a left/right pair, drawn
    in body order; with ``limb_std == 0`` nothing is drawn.
    """
    out = np.ones(len(body_names))
    draws: dict[str, float] = {}
    for b, name in enumerate(body_names[1:], start=1):
        z = 0.0
        if limb_std > 0.0:
            key = pair_name(name, body_names)
            if key not in draws:
                draws[key] = float(np.clip(rng.standard_normal(), -LIMB_CLIP_STD, LIMB_CLIP_STD))
            z = draws[key]
        out[b] = scale * (1.0 + limb_std * z)
    return out


def scaled_mjspec(path: str | Path, body_names: tuple[str, ...], factors: np.ndarray) -> mujoco.MjSpec:
    """The model file's ``MjSpec`` with every segment ``b`` scaled by ``factors[b]`` (see the module doc).

    body_names: the compiled model's body names (index = body id), to map spec bodies to factors.
    """
    spec = mujoco.MjSpec.from_file(str(path))
    index = {name: i for i, name in enumerate(body_names)}
    for body in spec.bodies:
        if body.name not in index or index[body.name] == 0:
            continue
        f = float(factors[index[body.name]])
        parent = body.parent
        # The offset from the parent is the parent segment's length; the root's (its standing height) is its own.
        f_offset = f if parent is None or parent.name not in index or index[parent.name] == 0 \
            else float(factors[index[parent.name]])
        body.pos = np.asarray(body.pos) * f_offset
        for geom in body.geoms:
            geom.pos = np.asarray(geom.pos) * f
            geom.size = np.asarray(geom.size) * f
            fromto = np.asarray(geom.fromto)
            if np.all(np.isfinite(fromto)):
                geom.fromto = fromto * f
        for site in body.sites:
            site.pos = np.asarray(site.pos) * f
            site.size = np.asarray(site.size) * f
        for joint in body.joints:
            joint.pos = np.asarray(joint.pos) * f
    return spec
