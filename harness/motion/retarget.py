"""Retargeting: source joint positions over time -> humanoid56 configurations, one path for every format.

Steps (``retarget``):

1. **Units and up axis.** Source positions ``(T, J, 3)`` are multiplied by ``unit_m`` (metres per source
   unit) and turned z-up. CMU skeletons are y-up with x to the subject's left and z forward, so the proper
   rotation ``(x, y, z) -> (z, x, y)`` makes them x forward, y left, z up like humanoid56 (no mirroring).
2. **Resampling** to the output frame rate (linear in time), so that only the output frames are solved.
3. **Targets with humanoid proportions.** Each mapped humanoid body ``b`` follows its source joint
   through the direction from its nearest mapped ancestor ``a``:
   ``target_b = target_a + L_ab * unit(src_b - src_a)`` with ``L_ab`` the humanoid's own distance between
   the two joint centres (at the zero pose). A site (a body-fixed point, ``skeletons.SITES``) does the
   same from its own body's origin, or that body's nearest mapped ancestor: the toe tips so drive the
   toe joints, which no joint centre below them could. A mapped point that sits on another in every frame
   (a BVH end site of zero length, as Bandai's toe ends) has no direction and is not a target (``_distinct``). Source and humanoid proportions differ (CMU's spine and neck split the trunk
   differently from humanoid56), so matching raw positions would leave centimetres of error that no pose
   can remove; matching directions keeps the pose and lets the humanoid's bone lengths stand. The hips
   are placed rigidly on the pelvis (``target_pelvis + R_base offset``), because the source's hip-joint
   bones do not match the humanoid's pelvis shape. The pelvis target is the source root times the
   **height scale** ``s`` (humanoid ankle-to-head chain length over the source's), so that strides and
   jump heights scale with the body.
4. **Base** position from the pelvis target, orientation from the hips line (y) and the spine (z).
5. **IK** per frame over the base pose (6) and the 50 angles within their ranges (``harness.motion.ik``:
   bounded Levenberg-Marquardt with MuJoCo Jacobians, continuation from the previous frame, restarts
   from analytic limb seeds where the residual is large or jumps).
6. **Levelling and grounding**: captured floors are not always level (CMU's walks climb a few
   centimetres over three metres); with ``level_floor`` the plane through the stance feet
   (``z = a x + b y + c``, fitted when the stance points span at least ``LEVEL_MIN_SPAN`` m) is removed
   by moving the base down by ``a x + b y`` at its position. Then the clip is shifted vertically so
   that the floor is at z = 0, the floor being the ``GROUND_PERCENTILE``-th percentile of the lowest
   point of each foot over the frames where that foot is in stance (``ground_height``). A percentile
   rather than the clip's minimum: one frame where a toe box dips (a toe-off the source's toe bone does
   not quite follow, a heel strike) would otherwise lift every stance frame off the floor.

The residual reported is the distance between each target and the body point that follows it, metres,
in humanoid scale (the "scale-normalised" residual).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from harness import geometry
from harness.body import BodyModel, geom_z_range
from harness.errors import HarnessError
from harness.motion.ik import DEFAULT_DAMPING, DEFAULT_ITERATIONS, DEFAULT_POSTURE, solve_ik
from harness.motion.skeletons import SITES, resolve_correspondence

REQUIRED_BODIES = ("pelvis", "lfemur", "rfemur")
#: A mapped point this near (m) another mapped point in every frame has no direction of its own.
COINCIDENT_M = 1e-3
HEIGHT_CHAIN = ("lfoot", "ltibia", "lfemur", "pelvis", "lowerback", "upperback", "thorax", "lowerneck", "upperneck", "head")


class RetargetError(HarnessError):
    """A source skeleton that cannot be retargeted (for example, without hips or spine)."""


@dataclass(frozen=True)
class RetargetResult:
    """qpos ``(T, 57)`` at ``fps``; targets ``(T, K, 3)`` metres (world, grounded like qpos) for
    ``target_bodies`` ``(K,)`` humanoid body or site names; residual ``(T, K)`` metres; scale: the height scale ``s``
    (humanoid per source metre); source_positions ``(T, J, 3)``: the source joints in metres, z-up,
    resampled, scaled by ``s`` and shifted like the targets (for drawing)."""

    qpos: np.ndarray
    fps: float
    targets: np.ndarray
    target_bodies: tuple[str, ...]
    residual: np.ndarray
    scale: float
    source_positions: np.ndarray


def y_up_to_z_up(positions: np.ndarray) -> np.ndarray:
    """``(..., 3)`` from y-up (x left, z forward: CMU) to z-up (x forward, y left): ``(x, y, z) -> (z, x, y)``."""
    p = np.asarray(positions, dtype=float)
    return np.stack([p[..., 2], p[..., 0], p[..., 1]], axis=-1)


def resample_positions(positions: np.ndarray, fps: float, fps_out: float) -> np.ndarray:
    """Linear resampling ``(T, J, 3)`` at ``fps`` to ``fps_out`` over the same time span."""
    n_in = len(positions)
    n_out = int(np.floor((n_in - 1) / fps * fps_out + 1e-9)) + 1
    t = np.arange(n_out) * (fps / fps_out)
    i0 = np.minimum(np.floor(t).astype(int), max(n_in - 2, 0))
    a = (t - i0)[:, None, None]
    i1 = np.minimum(i0 + 1, n_in - 1)
    return (1.0 - a) * positions[i0] + a * positions[i1]


def _mapped_ancestor(body: BodyModel, bid: int, mapped: set[int]) -> int:
    p = int(body.model.body_parentid[bid])
    while p not in mapped:
        if p == 0:
            raise RetargetError(f"body {body.body_names[bid]!r} has no mapped ancestor (is the pelvis mapped?)")
        p = int(body.model.body_parentid[p])
    return p


def _zero_origins(body: BodyModel) -> np.ndarray:
    from harness.body import body_origins

    return np.vstack([np.zeros((1, 3)), body_origins(body, body.zero_qpos(), frame="base")])


def target_points(body: BodyModel, names: list[str] | tuple[str, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Humanoid target names (bodies or ``SITES``) -> body ids ``(K,)`` and points in those bodies' frames
    ``(K, 3)`` metres (zero for a body: its origin)."""
    ids, local = [], []
    for name in names:
        bname, point = SITES[name] if name in SITES else (name, (0.0, 0.0, 0.0))
        ids.append(body.body_id(bname))
        local.append(point)
    return np.array(ids, dtype=int), np.array(local, dtype=float).reshape(-1, 3)


def height_scale(body: BodyModel, src: np.ndarray, bodies: list[int]) -> float:
    """Humanoid over source length of the ankle-to-head chain through the mapped bodies (mean over frames).

    ``src`` ``(T, K, 3)`` source positions of ``bodies`` ``(K,)`` body ids, metres."""
    origins = _zero_origins(body)
    chain = [body.body_id(n) for n in HEIGHT_CHAIN if body.body_id(n) in bodies]
    if len(chain) < 3:
        raise RetargetError("the source maps too few of the ankle-to-head bodies to measure its height")
    idx = [bodies.index(b) for b in chain]
    src_len = np.linalg.norm(np.diff(src[:, idx], axis=1), axis=2).sum(axis=1).mean()
    hum_len = np.linalg.norm(np.diff(origins[chain], axis=0), axis=1).sum()
    return float(hum_len / src_len)


def base_frames(pelvis: np.ndarray, left_hip: np.ndarray, right_hip: np.ndarray, spine: np.ndarray) -> np.ndarray:
    """Base orientations ``(T, 4)`` from the hips line (y, to the left) and the pelvis-to-spine direction (z)."""
    z = spine - pelvis
    z /= np.linalg.norm(z, axis=-1, keepdims=True)
    y = left_hip - right_hip
    y -= np.sum(y * z, axis=-1, keepdims=True) * z
    y /= np.linalg.norm(y, axis=-1, keepdims=True)
    x = np.cross(y, z)
    return geometry.from_matrix(np.stack([x, y, z], axis=-1))


def proportional_targets(body: BodyModel, src: np.ndarray, bodies: list[int], scale: float,
                         local: np.ndarray | None = None) -> np.ndarray:
    """Targets ``(T, K, 3)`` with humanoid bone lengths and the source's directions (module docstring, step 3).

    ``src`` ``(T, K, 3)`` metres z-up for the points ``(bodies[k], local[k])`` (body ids and points in
    their frames, ``local`` ``(K, 3)`` defaulting to the origins; a non-zero point is a site); the
    origins of pelvis, lfemur and rfemur must be among them."""
    origins = _zero_origins(body)
    local = np.zeros((len(bodies), 3)) if local is None else np.asarray(local, dtype=float)
    is_site = np.any(local != 0.0, axis=1)
    # At the zero pose every body frame is parallel to the world, so a point sits at origin + local.
    rest = origins[bodies] + local
    mapped = {b for b, site in zip(bodies, is_site) if not site}
    k_of = {b: k for k, (b, site) in enumerate(zip(bodies, is_site)) if not site}
    pelvis, lhip, rhip = (body.body_id(n) for n in REQUIRED_BODIES)
    spine = next((body.body_id(n) for n in ("thorax", "upperback", "lowerneck") if body.body_id(n) in mapped), None)
    if spine is None:
        raise RetargetError("the source maps no spine joint (thorax, upperback or lowerneck)")
    out = np.empty_like(src)
    out[:, k_of[pelvis]] = scale * src[:, k_of[pelvis]]
    quat = base_frames(src[:, k_of[pelvis]], src[:, k_of[lhip]], src[:, k_of[rhip]], src[:, k_of[spine]])
    # Parents before children: body ids in MuJoCo are in tree order; sites hang off finished origins.
    order = sorted(range(len(bodies)), key=lambda k: (bool(is_site[k]), bodies[k]))
    for k in order:
        b = bodies[k]
        if b == pelvis and not is_site[k]:
            continue
        a = b if is_site[k] and b in mapped else _mapped_ancestor(body, b, mapped)
        if a == pelvis and not is_site[k] and int(body.model.body_parentid[b]) == pelvis:
            out[:, k] = out[:, k_of[a]] + geometry.rotate(quat, rest[k] - origins[pelvis])
            continue
        d = src[:, k] - src[:, k_of[a]]
        d /= np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-9)
        out[:, k] = out[:, k_of[a]] + np.linalg.norm(rest[k] - origins[a]) * d
    return out


#: A foot whose ankle moves slower than this (m/s, horizontally) is taken to be in stance.
STANCE_SPEED = 0.25
#: Percentile (of the lowest point of each stance foot over a clip) that is put at z = 0.
GROUND_PERCENTILE = 10.0


def foot_lows(body: BodyModel, qpos: np.ndarray, fps: float, speed: float = STANCE_SPEED
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per frame and foot (left, right): the lowest point of the foot and toes geoms ``(T, 2)`` (m, world
    z), the ankle position ``(T, 2, 3)`` (m, world) and the stance mask ``(T, 2)`` (ankle moving
    horizontally slower than ``speed`` m/s)."""
    from harness.body import body_origins

    qpos = np.asarray(qpos, dtype=float)
    origins = body_origins(body, qpos)
    low = np.empty((len(qpos), 2))
    ankle = np.empty((len(qpos), 2, 3))
    for i, side in enumerate(("l", "r")):
        ankle[:, i] = origins[:, body.body_id(f"{side}foot") - 1]
        geoms = np.flatnonzero(np.isin(body.model.geom_bodyid, [body.body_id(f"{side}foot"),
                                                                 body.body_id(f"{side}toes")]))
        low[:, i] = geom_z_range(body, qpos, geoms)[:, :, 0].min(axis=1)
    v = np.linalg.norm(geometry.finite_difference(ankle[:, :, :2], 1.0 / fps), axis=2)
    return low, ankle, v < speed


def ground_height(body: BodyModel, qpos: np.ndarray, fps: float, percentile: float = GROUND_PERCENTILE) -> float:
    """Height (m) of the floor under a clip ``(T, 57)``: the ``percentile`` of the lowest point of each
    foot over the (frame, foot) pairs in stance (over all pairs if none is in stance)."""
    low, _, stance = foot_lows(body, qpos, fps)
    return float(np.percentile(low[stance] if stance.any() else low, percentile))


def _distinct(positions: np.ndarray, joint_names: list[str], correspondence: dict[str, str]) -> dict[str, str]:
    """The correspondence without the points that sit on another mapped point in every frame (a BVH end site
    of zero length, as Bandai's toe ends). A target takes its direction from the point it hangs off, and a
    zero-length bone has none: its target would land on that point, and fitting it folds the bone between them
    (Bandai's toes 0.9 rad down, its feet 0.4 rad up, whatever the motion). Sites are dropped before bodies."""
    kept = dict(correspondence)
    for joint in sorted(correspondence, key=lambda j: correspondence[j] not in SITES):
        at = positions[:, joint_names.index(joint)]
        if any(np.all(np.linalg.norm(at - positions[:, joint_names.index(other)], axis=-1) < COINCIDENT_M)
               for other in kept if other != joint):
            del kept[joint]
    return kept


def retarget(positions: np.ndarray, joint_names: tuple[str, ...] | list[str], fps: float, *,
             unit_m: float = 1.0, up: str = "y", fps_out: float | None = 30.0,
             mapping: dict[str, str | None] | None = None, body: BodyModel | None = None,
             damping: float = DEFAULT_DAMPING, iterations: int = DEFAULT_ITERATIONS,
             posture: float = DEFAULT_POSTURE, level_floor: bool = True, where: str = "source skeleton") -> RetargetResult:
    """Source joint positions ``(T, J, 3)`` (source units, ``up`` axis ``"y"`` or ``"z"``) at ``fps`` ->
    humanoid56 configurations at ``fps_out`` (None: keep ``fps``). See the module docstring for the steps."""
    body = body or BodyModel.load()
    if up not in ("y", "z"):
        raise RetargetError(f"{where}: up axis must be 'y' or 'z', got {up!r}")
    positions = np.asarray(positions, dtype=float) * unit_m
    if positions.ndim != 3 or positions.shape[1] != len(joint_names) or positions.shape[2] != 3:
        raise RetargetError(f"{where}: positions must be (T, {len(joint_names)}, 3), got {positions.shape}")
    if len(positions) < 2:
        raise RetargetError(f"{where}: needs at least 2 frames, got {len(positions)}")
    correspondence = _distinct(positions, list(joint_names), resolve_correspondence(joint_names, mapping,
                                                                                   body.body_names, where))
    missing = [b for b in REQUIRED_BODIES if b not in correspondence.values()]
    if missing:
        raise RetargetError(f"{where}: no source joint drives {', '.join(missing)} (needed for the base)")
    if up == "y":
        positions = y_up_to_z_up(positions)
    if fps_out is not None and fps_out != fps:
        positions = resample_positions(positions, fps, fps_out)
    fps_final = float(fps_out or fps)
    # Body origins in tree order, then sites (in SITES order).
    names = sorted(correspondence.values(),
                   key=lambda n: (n in SITES, list(SITES).index(n) if n in SITES else body.body_id(n)))
    joint_of = {b: j for j, b in correspondence.items()}
    src = positions[:, [list(joint_names).index(joint_of[n]) for n in names]]
    ids, local = target_points(body, names)
    bodies = [int(b) for b in ids]
    origin_k = [k for k, n in enumerate(names) if n not in SITES]
    scale = height_scale(body, src[:, origin_k], [bodies[k] for k in origin_k])
    targets = proportional_targets(body, src, bodies, scale, local)
    k_pelvis = bodies.index(body.body_id("pelvis"))
    init = body.zero_qpos()
    init[:3] = targets[0, k_pelvis]
    spine = next(n for n in ("thorax", "upperback", "lowerneck") if body.body_id(n) in bodies)
    init[3:7] = base_frames(*(src[0, bodies.index(body.body_id(n))] for n in ("pelvis", "lfemur", "rfemur", spine)))
    qpos, residual = solve_ik(body, targets, ids, init, damping=damping, iterations=iterations,
                              posture=posture, target_local=local, target_names=tuple(names))
    tilt = floor_tilt(body, qpos, fps_final) if level_floor else np.zeros(len(qpos))
    qpos[:, 2] -= tilt
    targets[:, :, 2] -= tilt[:, None]
    dz = ground_height(body, qpos, fps_final)
    qpos[:, 2] -= dz
    targets[:, :, 2] -= dz
    # The raw source skeleton at humanoid scale, moved with the targets (its root on the pelvis target).
    shown = positions * scale
    shown += (targets[:, k_pelvis] - scale * src[:, k_pelvis])[:, None]
    return RetargetResult(qpos=qpos, fps=fps_final, targets=targets,
                          target_bodies=tuple(names), residual=residual,
                          scale=scale, source_positions=shown)


def stance_foot_heights(body: BodyModel, qpos: np.ndarray, fps: float, speed: float = STANCE_SPEED) -> np.ndarray:
    """Lowest point (m, world z) of each foot (foot and toes geoms) on the frames where that foot's ankle
    moves horizontally slower than ``speed`` m/s: a 1-D array over (frame, foot) pairs in stance."""
    low, _, stance = foot_lows(body, qpos, fps, speed)
    return np.concatenate([low[stance[:, 0], 0], low[stance[:, 1], 1]])


#: Least horizontal extent (m) of the stance points before a floor slope is fitted: in-place motions
#: (punches, jumps on the spot) leave the slope undetermined, and their floor is left as captured.
LEVEL_MIN_SPAN = 1.0


def floor_tilt(body: BodyModel, qpos: np.ndarray, fps: float, speed: float = STANCE_SPEED) -> np.ndarray:
    """Height (m) of the captured floor's slope under the base, ``(T,)``: ``a x_t + b y_t`` with ``a, b`` the
    least-squares plane through the lowest points of the feet in stance (zeros if the stance points span
    less than ``LEVEL_MIN_SPAN`` m)."""
    low, ankle, stance = foot_lows(body, qpos, fps, speed)
    pts = np.column_stack([ankle[stance][:, :2], low[stance]])
    if len(pts) < 3 or np.ptp(pts[:, :2], axis=0).max() < LEVEL_MIN_SPAN:
        return np.zeros(len(qpos))
    coef = np.linalg.lstsq(np.column_stack([pts[:, :2], np.ones(len(pts))]), pts[:, 2], rcond=None)[0]
    return np.asarray(qpos, dtype=float)[:, :2] @ coef[:2]
