"""Area-uniform samples of points on the body surface, with outward normals.

Supported geom types are the primitives the humanoid is built from: sphere, capsule, box (and cylinder).
Each sample is stored in the frame of the body that carries its geom, so that ``harness.body.kinematics``
can move it with the body. With ``exclude_interior`` (the default), samples that lie inside another geom of
the body at the zero pose (for example where the thigh capsule enters the pelvis) are rejected, so the
sample is area-uniform over the exposed surface of the union of geoms.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import numpy as np

from harness.body.model import BodyModel
from harness.errors import BodyError

SPHERE, CAPSULE, BOX, CYLINDER = (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE),
                                  int(mujoco.mjtGeom.mjGEOM_BOX), int(mujoco.mjtGeom.mjGEOM_CYLINDER))
SUPPORTED = {SPHERE: "sphere", CAPSULE: "capsule", BOX: "box", CYLINDER: "cylinder"}


@dataclass(frozen=True)
class SurfacePoints:
    """Body-fixed surface points.

    body: ``(P,)`` int, MuJoCo body id carrying each point.
    geom: ``(P,)`` int, geom the point was sampled on.
    local: ``(P, 3)`` position in the body frame, metres.
    normal: ``(P, 3)`` outward unit normal in the body frame.
    """

    body: np.ndarray
    geom: np.ndarray
    local: np.ndarray
    normal: np.ndarray

    def __len__(self) -> int:
        return len(self.body)

    def subset(self, index) -> "SurfacePoints":
        return SurfacePoints(self.body[index], self.geom[index], self.local[index], self.normal[index])


def geom_area(geom_type: int, size: np.ndarray) -> float:
    """Surface area of a primitive geom from MuJoCo's ``geom_size`` (half-sizes), square metres."""
    if geom_type == SPHERE:
        return 4.0 * np.pi * size[0] ** 2
    if geom_type == CAPSULE:
        r, h = size[0], size[1]
        return 4.0 * np.pi * r * h + 4.0 * np.pi * r**2
    if geom_type == BOX:
        a, b, c = size
        return 8.0 * (a * b + b * c + c * a)
    if geom_type == CYLINDER:
        r, h = size[0], size[1]
        return 4.0 * np.pi * r * h + 2.0 * np.pi * r**2
    raise BodyError(f"geom type {geom_type} is not supported for surface sampling "
                     f"(supported: {', '.join(SUPPORTED.values())})")


def geom_sdf(geom_type: int, size: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Signed distance of points ``(N, 3)`` given in the geom's own frame; negative inside."""
    p = np.asarray(p, dtype=float)
    if geom_type == SPHERE:
        return np.linalg.norm(p, axis=1) - size[0]
    if geom_type == CAPSULE:
        r, h = size[0], size[1]
        axial = np.clip(p[:, 2], -h, h)
        return np.linalg.norm(p - np.stack([0 * axial, 0 * axial, axial], axis=1), axis=1) - r
    if geom_type == BOX:
        q = np.abs(p) - size[:3]
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    if geom_type == CYLINDER:
        r, h = size[0], size[1]
        q = np.stack([np.linalg.norm(p[:, :2], axis=1) - r, np.abs(p[:, 2]) - h], axis=1)
        return np.linalg.norm(np.maximum(q, 0.0), axis=1) + np.minimum(q.max(axis=1), 0.0)
    raise BodyError(f"geom type {geom_type} is not supported (supported: {', '.join(SUPPORTED.values())})")


def _unit_vectors(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.standard_normal((n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _sample_geom(geom_type: int, size: np.ndarray, n: int, rng: np.random.Generator
                 ) -> tuple[np.ndarray, np.ndarray]:
    """``n`` area-uniform points and outward normals on one primitive, in its own frame."""
    if geom_type == SPHERE:
        nrm = _unit_vectors(rng, n)
        return size[0] * nrm, nrm
    if geom_type in (CAPSULE, CYLINDER):
        r, h = size[0], size[1]
        side_area = 4.0 * np.pi * r * h
        on_side = rng.random(n) < side_area / geom_area(geom_type, size)
        phi = rng.uniform(0.0, 2.0 * np.pi, n)
        z = rng.uniform(-h, h, n)
        nrm = np.stack([np.cos(phi), np.sin(phi), np.zeros(n)], axis=1)
        pos = np.stack([r * nrm[:, 0], r * nrm[:, 1], z], axis=1)
        ends = ~on_side
        k = int(ends.sum())
        if geom_type == CAPSULE:
            # Each hemispherical cap: a unit vector on the sphere, its sign of z picks the cap.
            cap = _unit_vectors(rng, k)
            pos[ends] = r * cap + np.outer(np.sign(cap[:, 2]) * h, [0.0, 0.0, 1.0])
            nrm[ends] = cap
        else:
            # Disk: radius with density proportional to radius, then either end.
            rad = r * np.sqrt(rng.random(k))
            ang = rng.uniform(0.0, 2.0 * np.pi, k)
            sgn = np.where(rng.random(k) < 0.5, -1.0, 1.0)
            pos[ends] = np.stack([rad * np.cos(ang), rad * np.sin(ang), sgn * h], axis=1)
            nrm[ends] = np.stack([0 * sgn, 0 * sgn, sgn], axis=1)
        return pos, nrm
    if geom_type == BOX:
        half = np.asarray(size[:3], dtype=float)
        # Faces in pairs normal to x, y, z; a face normal to axis i has area 4 * prod(other half-sizes).
        face_area = np.array([half[1] * half[2], half[0] * half[2], half[0] * half[1]])
        axis = rng.choice(3, size=n, p=face_area / face_area.sum())
        sgn = np.where(rng.random(n) < 0.5, -1.0, 1.0)
        pos = rng.uniform(-1.0, 1.0, (n, 3)) * half
        pos[np.arange(n), axis] = sgn * half[axis]
        nrm = np.zeros((n, 3))
        nrm[np.arange(n), axis] = sgn
        return pos, nrm
    raise BodyError(f"geom type {geom_type} is not supported (supported: {', '.join(SUPPORTED.values())})")


def _inside_other_geoms(body: BodyModel, geom: np.ndarray, body_id: np.ndarray, local: np.ndarray,
                        tol: float) -> np.ndarray:
    """Whether each point lies deeper than ``tol`` inside a geom other than its own, at the zero pose."""
    m, d = body.model, mujoco.MjData(body.model)
    mujoco.mj_kinematics(m, d)
    world = d.xpos[body_id] + np.einsum("pij,pj->pi", d.xmat[body_id].reshape(-1, 3, 3), local)
    inside = np.zeros(len(local), dtype=bool)
    for g in body.body_geoms:
        rot = d.geom_xmat[g].reshape(3, 3)
        in_geom = (world - d.geom_xpos[g]) @ rot
        inside |= (geom_sdf(int(m.geom_type[g]), m.geom_size[g], in_geom) < -tol) & (geom != g)
    return inside


def sample_surface(body: BodyModel, n: int, rng: np.random.Generator, exclude_interior: bool = True,
                   interior_tol: float = 1e-6) -> SurfacePoints:
    """Draw ``n`` points uniformly by area over the humanoid's geoms (deterministic for a given ``rng``)."""
    if n < 0:
        raise BodyError(f"number of surface points must be >= 0, got {n}")
    m = body.model
    geoms = body.body_geoms
    for g in geoms:
        if int(m.geom_type[g]) not in SUPPORTED:
            name = mujoco.mj_id2name(m, mujoco.mjtObj.mjOBJ_GEOM, int(g))
            raise BodyError(f"geom {name!r} has a type that cannot be sampled "
                             f"(supported: {', '.join(SUPPORTED.values())})")
    if n == 0:
        return SurfacePoints(np.empty(0, int), np.empty(0, int), np.empty((0, 3)), np.empty((0, 3)))
    areas = np.array([geom_area(int(m.geom_type[g]), m.geom_size[g]) for g in geoms])
    chunks: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
    have = 0
    while have < n:
        batch = max(2 * (n - have), 16)
        pick = geoms[rng.choice(len(geoms), size=batch, p=areas / areas.sum())]
        local = np.empty((batch, 3))
        normal = np.empty((batch, 3))
        for g in np.unique(pick):
            sel = pick == g
            pos, nrm = _sample_geom(int(m.geom_type[g]), m.geom_size[g], int(sel.sum()), rng)
            rot = np.empty(9)
            mujoco.mju_quat2Mat(rot, m.geom_quat[g])
            rot = rot.reshape(3, 3)
            local[sel] = m.geom_pos[g] + pos @ rot.T
            normal[sel] = nrm @ rot.T
        body_id = m.geom_bodyid[pick].astype(int)
        keep = np.ones(batch, dtype=bool)
        if exclude_interior:
            keep = ~_inside_other_geoms(body, pick, body_id, local, interior_tol)
        chunks.append((body_id[keep], pick[keep], local[keep], normal[keep]))
        have += int(keep.sum())
    body_id, geom, local, normal = (np.concatenate(parts)[:n] for parts in zip(*chunks))
    return SurfacePoints(body_id, geom, local, normal)


def even_surface(body: BodyModel, n: int, rng: np.random.Generator, oversample: int = 8) -> SurfacePoints:
    """``n`` points spread evenly over the humanoid's exposed surface: ``oversample`` times as many area-uniform
    candidates (``sample_surface``); each geom gets its candidates' share of ``n`` (largest remainders), chosen
    among them by farthest-point selection (each next point the candidate farthest from those chosen)."""
    if oversample < 1:
        raise BodyError(f"oversample must be >= 1, got {oversample}")
    cand = sample_surface(body, oversample * n, rng)
    if n == 0:
        return cand
    members = [np.flatnonzero(cand.geom == g) for g in body.body_geoms]
    exact = n * np.array([len(m) for m in members]) / len(cand)
    share = np.floor(exact).astype(int)
    share[np.argsort(share - exact)[:n - share.sum()]] += 1      # at most a geom's candidates: oversample >= 1
    chosen = []
    for mine, k in zip(members, share):
        if k == 0:
            continue
        pts = cand.local[mine]
        first = int(rng.integers(len(mine)))
        picks = [first]
        dist = np.linalg.norm(pts - pts[first], axis=1)
        for _ in range(k - 1):
            i = int(np.argmax(dist))
            picks.append(i)
            dist = np.minimum(dist, np.linalg.norm(pts - pts[i], axis=1))
        chosen.extend(mine[picks])
    return cand.subset(np.array(chosen))
