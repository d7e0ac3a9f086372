"""Flows of track-video's pipeline on rendered cloth against the true image motion of the surface point under
each feature (issue 62; prints a table, exits 1 when the median misses the requirement).

    MUJOCO_GL=egl PYTHONPATH=. python benchmarks/video_flows.py [--runs 20] [--scenario scenarios/video.yaml]

The runs are the video-mode runs of the scenario (the same motions, cameras and walls that ``harness evaluate``
scores), the first ``--runs`` of each wall in plan order. For each run the subject is rendered in cloth and
followed by the pipeline exactly as ``observation.mode: video`` does (``harness.scene.footage``). For each flow
row ``(u, v, du, dv)`` of frame ``t`` the feature started at ``p0 = (u, v) - (du, dv) / fps`` in frame ``t - 1``; a
ray from the camera centre through ``p0`` (``mj_multiRay``: body, floor and obstacles, as rendered) finds the
surface point under it at ``t - 1``; that point, fixed in its body's frame, is projected at ``t``; the endpoint
error is the distance between it and ``(u, v)``. A feature whose ray meets the floor, an obstacle or nothing is
off the body (its true motion is zero: the scene is static) and counted apart.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections import defaultdict
from pathlib import Path

import mujoco
import numpy as np

from harness.body import nominal_body
from harness.pinhole import project
from harness.scene.footage import follow_subject, render_footage
from harness.scene.occluders import OCCLUDER_GROUP
from harness.scene.setup import build_setup
from harness.scene.visibility import BODY_GROUP

REQUIRED_MEDIAN_PX = 0.5     # the requirement: median endpoint error per frame
FLOOR_GROUP = 2              # the model file's floor
_RAY_GROUPS = np.zeros(6, dtype=np.uint8)
_RAY_GROUPS[[BODY_GROUP, FLOOR_GROUP, OCCLUDER_GROUP]] = 1


def surface_motion(setup, qpos: np.ndarray, t: int, start: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Where the surface points under pixels ``start (M, 2)`` of frame ``t - 1`` are at frame ``t``: ``(M, 2)``
    px, and whether each lies on the body ``(M,)`` (else the start pixel itself: the scene does not move)."""
    scene, traj = setup.scene, setup.camera
    m, d, intr = scene.model, scene.data, traj.intrinsics
    scene.pose(qpos[t - 1])
    rays = np.stack([(start[:, 0] - intr.cx) / intr.fx, (start[:, 1] - intr.cy) / intr.fy,
                     np.ones(len(start))], axis=1) @ traj.rot[t - 1].T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    geom = np.empty(len(start), dtype=np.int32)
    dist = np.empty(len(start))
    mujoco.mj_multiRay(m, d, traj.pos[t - 1].astype(float), np.ascontiguousarray(rays.ravel()), _RAY_GROUPS, 1,
                       -1, geom, dist, None, len(start), 1000.0)
    body = m.geom_bodyid[np.maximum(geom, 0)]
    on_body = (geom >= 0) & (body > 0)
    hit = traj.pos[t - 1] + rays * dist[:, None]
    local = np.einsum("nji,nj->ni", d.xmat[body].reshape(-1, 3, 3), hit - d.xpos[body])
    scene.pose(qpos[t])
    world = d.xpos[body] + np.einsum("nij,nj->ni", d.xmat[body].reshape(-1, 3, 3), local)
    cam = np.einsum("ji,nj->ni", traj.rot[t], world - traj.pos[t])
    moved = project(intr, np.where(on_body[:, None], cam, 1.0))
    return np.where(on_body[:, None], moved, start), on_body


def run_errors(run) -> dict:
    """Endpoint errors of one run's video flows: on-body errors (px), off-body count, frames, seconds."""
    from harness.evaluation.pipeline import test_motion
    from harness.evaluation.scenario import scene_spec
    from harness.randomness import named_generator

    motion = test_motion(run)
    spec = scene_spec(run.config, named_generator(run.seed, "scene"))      # as pipeline.run_inputs draws it
    setup = build_setup(motion, spec, nominal_body())
    qpos, fps = setup.motion.qpos, setup.motion.fps
    t0 = time.perf_counter()
    frames, plate = render_footage(setup, qpos)
    t1 = time.perf_counter()
    result = follow_subject(frames, plate, fps)
    t2 = time.perf_counter()
    errors, off = [], 0
    person = result.people[0] if result.people else None
    for t in range(1, len(qpos)):
        rows = person.flows.get(t) if person is not None else None
        if rows is None or len(rows) == 0:
            continue
        end = rows[:, :2]
        truth, on_body = surface_motion(setup, qpos, t, end - rows[:, 2:] / fps)
        errors.append(np.linalg.norm(end - truth, axis=1)[on_body])
        off += int((~on_body).sum())
    e = np.concatenate(errors) if errors else np.empty(0)
    return {"errors": e, "off": off, "frames": len(qpos) - 1, "render_s": t1 - t0, "follow_s": t2 - t1}


def main(argv=None) -> int:
    from harness.evaluation.runner import plan
    from harness.evaluation.loading import load_scenario

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenario", default="scenarios/video.yaml")
    ap.add_argument("--runs", type=int, default=20, help="video-mode runs per wall (plan order)")
    args = ap.parse_args(argv)
    t_start = time.perf_counter()
    scenario = load_scenario(args.scenario)
    by_wall = defaultdict(list)
    for run in plan(scenario, Path("results") / "cache"):
        if run.config.observation.mode == "video" and len(by_wall[run.config.occluders.amount]) < args.runs:
            by_wall[run.config.occluders.amount].append(run)
    print(f"| wall | runs | frames | flows per frame | off the body | median EPE (px) | p90 (px) | <= 0.5 px | "
          f"render ms/frame | pipeline ms/frame |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    ok = True
    for wall, runs in sorted(by_wall.items()):
        parts = [run_errors(r) for r in runs]
        e = np.concatenate([p["errors"] for p in parts])
        frames = sum(p["frames"] for p in parts)
        off = sum(p["off"] for p in parts)
        n = len(e) + off
        med = float(np.median(e))
        ok &= med <= REQUIRED_MEDIAN_PX
        print(f"| {wall:g} | {len(runs)} | {frames} | {n / frames:.1f} | {100 * off / n:.1f}% | {med:.3f} | "
              f"{np.percentile(e, 90):.3f} | {100 * np.mean(e <= 0.5):.1f}% | "
              f"{1e3 * sum(p['render_s'] for p in parts) / frames:.0f} | "
              f"{1e3 * sum(p['follow_s'] for p in parts) / frames:.1f} |", flush=True)
    print(f"\nrequirement: median endpoint error <= {REQUIRED_MEDIAN_PX} px per frame: {'met' if ok else 'MISSED'}; "
          f"{time.perf_counter() - t_start:.0f} s")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
