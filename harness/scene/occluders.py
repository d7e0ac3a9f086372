"""Obstacles between the camera and the subject, sized so that they hide a requested fraction of it.

An occluder is an upright geom standing in the world (``Obstacle``: a box, cylinder or capsule with its centre,
MuJoCo half-sizes and yaw about world z). Obstacles come from a preset or are given by hand
(``OccluderSpec.geoms``, in the subject's start frame, see ``custom_obstacles``). Presets are registered by
name and map one scalar ``size`` parameter to a list of boxes; coverage is monotone in it:

- ``none``: nothing.
- ``low_wall``: a wall across the line of sight, from the floor up to a height: hides the legs first.
- ``pillar``: a full-height column coming in from one side (seeded): hides that side first.
- ``boxes``: seeded random crates standing on the floor, added one by one until the coverage is reached.

Calibration: the occluders stand in a vertical plane across the initial line of sight, about halfway
between the camera and the nearest point of the subject's path. The achieved occlusion is measured on the
actual lines of sight (camera centre to every in-view marker, every frame) with a segment-box slab test,
and ``size`` is found by bisection so that the pooled fraction of in-view marker-frames whose line of
sight crosses an occluder equals the requested ``amount``. The ray caster then sees the same geometry.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import mujoco
import numba
import numpy as np

from harness import geometry
from harness.body.surface import BOX, CAPSULE, CYLINDER, geom_sdf
from harness.scene.camera import WORLD_UP, CameraTrajectory
from harness.scene.spec import OccluderGeom, OccluderSpec, SceneError

OCCLUDER_GROUP = 3                      # MuJoCo geom group of occluders (rays and renderer include it)
OCCLUDER_RGBA = (0.30, 0.34, 0.52, 1.0)
WALL_THICKNESS = 0.06                   # m
MARGIN = 0.3                            # m, lateral and vertical margin beyond the subject's lines of sight
MIN_CLEARANCE = 0.8                     # m, the nearest subject point must be this far from the camera
BISECTION_STEPS = 40
MAX_BOXES = 64
GEOM_TYPES = {"box": BOX, "cylinder": CYLINDER, "capsule": CAPSULE}


@dataclass(frozen=True)
class Obstacle:
    """An upright geom: centre ``(3,)`` world metres, MuJoCo half-sizes ``(3,)`` metres (box: half extents;
    cylinder: radius, half height; capsule: radius, half length of the cylindrical part), yaw (rad) about
    world z, and ``kind`` (``box``, ``cylinder``, ``capsule``)."""

    centre: np.ndarray
    half: np.ndarray
    yaw: float
    kind: str = "box"

    @property
    def geom_type(self) -> int:
        return GEOM_TYPES[self.kind]

    def to_local(self, points: np.ndarray) -> np.ndarray:
        """World points ``(..., 3)`` in the box's own frame."""
        c, s = np.cos(self.yaw), np.sin(self.yaw)
        d = np.asarray(points, float) - self.centre
        return np.stack([c * d[..., 0] + s * d[..., 1], -s * d[..., 0] + c * d[..., 1], d[..., 2]], axis=-1)

    def quat(self) -> np.ndarray:
        return np.array([np.cos(0.5 * self.yaw), 0.0, 0.0, np.sin(0.5 * self.yaw)])


def segments_blocked(start: np.ndarray, end: np.ndarray, boxes: list[Obstacle], eps: float = 1e-9) -> np.ndarray:
    """Whether each segment ``start -> end`` (both ``(R, 3)``) passes through any box before its end: ``(R,)``
    (boxes only: the presets' calibration; custom obstacles are measured by the ray caster).

    Slab test in each box frame: the segment ``a + s (b - a)``, ``s`` in [0, 1], meets the box if the
    intervals where it is inside each pair of faces overlap somewhere in [0, 1).
    """
    blocked = np.zeros(len(start), dtype=bool)
    start, end = np.ascontiguousarray(start, dtype=float), np.ascontiguousarray(end, dtype=float)
    for box in boxes:
        if box.kind != "box":
            raise SceneError(f"segments_blocked: {box.kind} obstacles are not supported (boxes only)")
        _blocked_by_box(start, end, np.asarray(box.centre, dtype=float), np.asarray(box.half, dtype=float),
                        np.cos(box.yaw), np.sin(box.yaw), eps, blocked)
    return blocked


@numba.njit(cache=True)
def _blocked_by_box(start, end, centre, half, c, s, eps, blocked):
    """``segments_blocked`` for one box, segment by segment into ``blocked`` (``|=``): the wall presets size their
    box by bisection, and numpy's two dozen array operations a call made it a quarter of a run's simulation."""
    a, b = np.empty(3), np.empty(3)
    for r in range(len(start)):
        for point, out in ((start[r], a), (end[r], b)):          # ``Obstacle.to_local``
            d0, d1, d2 = point[0] - centre[0], point[1] - centre[1], point[2] - centre[2]
            out[0], out[1], out[2] = c * d0 + s * d1, -s * d0 + c * d1, d2
        enter, leave = -np.inf, np.inf
        for k in range(3):
            d = b[k] - a[k]
            if abs(d) <= eps:             # parallel to the slab: inside it for all s, or never
                lo, hi = (-np.inf, np.inf) if abs(a[k]) <= half[k] else (np.inf, -np.inf)
            else:
                t1, t2 = (-half[k] - a[k]) / d, (half[k] - a[k]) / d
                lo, hi = min(t1, t2), max(t1, t2)
            enter, leave = max(enter, lo), min(leave, hi)
        if (enter < leave) and (leave > 0.0) and (enter < 1.0 - 1e-6):
            blocked[r] = True


@dataclass(frozen=True)
class _Layout:
    """Where occluders go: the plane across the initial line of sight, and the subject's extent in it.

    origin: camera centre at frame 0. forward/right: horizontal unit vectors. depth: plane distance (m).
    lateral: (min, max) of the lines of sight where they cross the plane (m, along ``right``).
    top: highest crossing height (m).
    """

    origin: np.ndarray
    forward: np.ndarray
    right: np.ndarray
    depth: float
    lateral: tuple[float, float]
    top: float

    def box(self, depth: float, lateral: tuple[float, float], height: tuple[float, float],
            thickness: float) -> Obstacle:
        centre = (self.origin[:2] + depth * self.forward[:2] + 0.5 * (lateral[0] + lateral[1]) * self.right[:2])
        yaw = float(np.arctan2(self.forward[1], self.forward[0]))
        half = np.array([0.5 * thickness, 0.5 * (lateral[1] - lateral[0]), 0.5 * (height[1] - height[0])])
        return Obstacle(np.append(centre, 0.5 * (height[0] + height[1])), half, yaw)


_PRESETS: dict[str, Callable[[_Layout, np.random.Generator], tuple[Callable[[float], list[Obstacle]], float]]] = {}


def preset(name: str):
    """Register ``factory(layout, rng) -> (boxes_of(size), max_size)`` under ``name``."""
    def register(factory):
        _PRESETS[name] = factory
        return factory
    return register


def preset_names() -> tuple[str, ...]:
    return tuple(_PRESETS)


@preset("none")
def _none(layout: _Layout, rng: np.random.Generator):
    return (lambda size: []), 0.0


@preset("low_wall")
def _low_wall(layout: _Layout, rng: np.random.Generator):
    lateral = (layout.lateral[0] - MARGIN, layout.lateral[1] + MARGIN)
    return (lambda h: [layout.box(layout.depth, lateral, (0.0, h), WALL_THICKNESS)] if h > 0 else []), \
        layout.top + MARGIN


@preset("pillar")
def _pillar(layout: _Layout, rng: np.random.Generator):
    from_left = bool(rng.random() < 0.5)
    lo, hi = layout.lateral[0] - MARGIN, layout.lateral[1] + MARGIN
    height = (0.0, layout.top + MARGIN)

    def boxes(w: float) -> list[Obstacle]:
        if w <= 0:
            return []
        side = (lo, lo + w) if from_left else (hi - w, hi)
        return [layout.box(layout.depth, side, height, 2.0 * WALL_THICKNESS)]
    return boxes, hi - lo


@preset("boxes")
def _boxes(layout: _Layout, rng: np.random.Generator):
    lo, hi = layout.lateral
    span = max(hi - lo, 0.2)
    drawn = []
    for _ in range(MAX_BOXES):
        width = rng.uniform(0.15, 0.4) * span
        centre = rng.uniform(lo, hi)
        height = rng.uniform(0.3, 1.0) * (layout.top + MARGIN)
        depth = layout.depth * rng.uniform(0.8, 1.1)
        thickness = rng.uniform(0.15, 0.4)
        drawn.append((depth, (centre - 0.5 * width, centre + 0.5 * width), height, thickness))

    def boxes(k: float) -> list[Obstacle]:
        # The first floor(k) crates at full height, the next one scaled by the fractional part.
        full, frac = int(np.floor(k)), k - np.floor(k)
        out = [layout.box(d, lat, (0.0, h), th) for d, lat, h, th in drawn[:full]]
        if frac > 0 and full < len(drawn):
            d, lat, h, th = drawn[full]
            out.append(layout.box(d, lat, (0.0, frac * h), th))
        return out
    return boxes, float(MAX_BOXES)


def _layout(traj: CameraTrajectory, marker_world: np.ndarray, in_view: np.ndarray) -> _Layout:
    origin = traj.pos[0]
    fwd = traj.look_at[0] - origin
    fwd[2] = 0.0
    if np.linalg.norm(fwd) < 1e-9:      # looking straight down the z axis is excluded by the spec
        fwd = traj.rot[0][:, 2].copy()
        fwd[2] = 0.0
    fwd /= np.linalg.norm(fwd)
    right = np.cross(fwd, WORLD_UP)
    pts = marker_world[in_view]
    cams = np.broadcast_to(traj.pos[:, None, :], marker_world.shape)[in_view]
    nearest = float(((pts - origin) @ fwd).min())
    if nearest < MIN_CLEARANCE:
        raise SceneError(f"camera.distance: the subject comes within {nearest:.2f} m of the camera, too close "
                         f"to place occluders between them (need {MIN_CLEARANCE} m)")
    depth = 0.5 * nearest
    # Crossing of every line of sight with the plane (x - origin) . fwd = depth.
    along = (pts - cams) @ fwd
    s = (depth - (cams - origin) @ fwd) / np.where(np.abs(along) > 1e-9, along, 1e-9)
    cross = cams + np.clip(s, 0.0, 1.0)[:, None] * (pts - cams)
    lateral = (cross - origin) @ right
    return _Layout(origin, fwd, right, depth, (float(lateral.min()), float(lateral.max())),
                   float(max(cross[:, 2].max(), 0.1)))


def sight_lines(traj: CameraTrajectory, marker_world: np.ndarray, in_view: np.ndarray
                ) -> tuple[np.ndarray, np.ndarray]:
    """The lines of sight of the in-view marker-frames: camera centres and markers, ``(R, 3)`` each."""
    cams = np.broadcast_to(traj.pos[:, None, :], marker_world.shape)[in_view]
    return np.ascontiguousarray(cams), np.ascontiguousarray(marker_world[in_view])


def coverage(boxes: list[Obstacle], lines: tuple[np.ndarray, np.ndarray]) -> float:
    """Pooled fraction of the lines of sight (``sight_lines``) that cross a box."""
    if not len(lines[0]):
        return 0.0
    return float(segments_blocked(*lines, boxes).mean())


def custom_obstacles(geoms: tuple[OccluderGeom, ...], start_pos: np.ndarray, start_heading: float
                     ) -> list[Obstacle]:
    """Obstacles given in the subject's start frame (origin at the base's xy at the first frame, on the floor;
    x along the initial heading ``start_heading`` rad) placed in the world."""
    c, s = np.cos(start_heading), np.sin(start_heading)
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    origin = np.array([start_pos[0], start_pos[1], 0.0])
    out = []
    for g in geoms:
        half = np.zeros(3)
        half[:len(g.size)] = g.size
        out.append(Obstacle(origin + rot @ np.asarray(g.pos, float), half, start_heading + np.deg2rad(g.yaw),
                            g.type))
    return out


def start_pose(base_pos: np.ndarray, base_quat: np.ndarray) -> tuple[np.ndarray, float]:
    """The subject's start frame from a motion's base ``(T, 3)``, ``(T, 4)``: first base xy and heading (rad)."""
    return np.asarray(base_pos)[0], float(geometry.heading(np.asarray(base_quat)[0]))


def build_occluders(spec: OccluderSpec, traj: CameraTrajectory, marker_world: np.ndarray, in_view: np.ndarray,
                    start: tuple[np.ndarray, float] = (np.zeros(3), 0.0)) -> list[Obstacle]:
    """The scene's obstacles: ``spec.geoms`` placed from the subject's ``start`` frame (``start_pose``), or
    boxes of ``spec.preset`` sized so that they hide ``spec.amount`` of the in-view marker-frames.

    marker_world: ``(T, N, 3)`` markers in the world (m). in_view: ``(T, N)`` bool, in front of the camera
    and inside the image. Raises ``SceneError`` if the amount cannot be reached.
    """
    if spec.geoms:
        return custom_obstacles(spec.geoms, *start)
    if spec.preset not in _PRESETS:
        raise SceneError(f"occluders.preset={spec.preset!r}: unknown preset; presets: {', '.join(_PRESETS)}")
    if spec.amount == 0.0 or spec.preset == "none":
        return []
    if not in_view.any():
        raise SceneError(f"occluders.preset={spec.preset!r}: the camera sees none of the subject, "
                         "there is nothing to hide")
    layout = _layout(traj, marker_world, in_view)
    boxes_of, top = _PRESETS[spec.preset](layout, np.random.default_rng(spec.seed))
    lines = sight_lines(traj, marker_world, in_view)           # the same for every size tried
    cover = lambda size: coverage(boxes_of(size), lines)  # noqa: E731
    if spec.preset == "boxes":
        # Add whole crates until the coverage is reached, then bisect within the last one.
        k = 0
        while k < top and cover(k + 1) < spec.amount:
            k += 1
        lo, hi = float(k), float(k + 1)
    else:
        lo, hi = 0.0, top
    if cover(hi) < spec.amount:
        raise SceneError(f"occluders.amount={spec.amount!r}: preset {spec.preset!r} hides at most "
                         f"{cover(hi):.2f} of the subject from this camera")
    for _ in range(BISECTION_STEPS):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if cover(mid) < spec.amount else (lo, mid)
    # The smallest size that reaches the amount within the bisection's resolution.
    return boxes_of(hi)


def check_camera_outside(boxes: list[Obstacle], camera_pos: np.ndarray, what: str) -> None:
    """Raise ``SceneError`` if a camera position ``(T, 3)`` lies inside (or on) an occluder; ``what`` names the
    occluders in the message (``occluders.preset='pillar'``, ``occluders.geoms``)."""
    for k, box in enumerate(boxes):
        inside = geom_sdf(box.geom_type, box.half, box.to_local(camera_pos)) <= 1e-3
        if inside.any():
            t = int(np.argmax(inside))
            raise SceneError(f"{what}: the camera at frame {t} (position "
                             f"{np.round(camera_pos[t], 2).tolist()} m) is inside occluder {k}", what.split("=")[0])


def add_occluder_geoms(mjspec: mujoco.MjSpec, boxes: list[Obstacle]) -> None:
    """Add the obstacles to the world body of a model being built, as geoms named ``occluder<k>`` in group 3."""
    for k, box in enumerate(boxes):
        mjspec.worldbody.add_geom(name=f"occluder{k}", type=mujoco.mjtGeom(box.geom_type), size=box.half,
                                  pos=box.centre, quat=box.quat(), group=OCCLUDER_GROUP, rgba=OCCLUDER_RGBA,
                                  contype=0, conaffinity=0)

