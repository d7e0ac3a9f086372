"""``harness scene-video``: the scene camera's image with the observed flow vectors drawn on it."""

from __future__ import annotations

import argparse

import numpy as np

from harness.commands import command
from harness.errors import HarnessError


def _args(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--motion", help="a saved Motion (.npz)")
    src.add_argument("--class", dest="label", help="a primitive from the procedural performer")
    p.add_argument("--seed", type=int, default=0, help="performer and observation seed")
    p.add_argument("--preset", default="none", help="occluder preset: none, low_wall, pillar, boxes")
    p.add_argument("--amount", type=float, default=0.0, help="fraction of the subject hidden by occluders")
    p.add_argument("--azimuth", type=float, default=30.0, help="degrees from the subject's initial heading")
    p.add_argument("--elevation", type=float, default=10.0, help="degrees above the look-at point")
    p.add_argument("--distance", type=float, default=4.0, help="metres from the look-at point")
    p.add_argument("--markers", type=int, default=100, help="number of surface markers")
    p.add_argument("--mode", default="geometric",
                   help="geometric, rendered (marker dots) or video (the body in cloth, track-video's pipeline)")
    p.add_argument("--noise", type=float, default=1.0, help="pixel noise (geometric mode), pixels")
    p.add_argument("--out", default="scene.mp4", help="video file (.mp4 or .gif)")
    p.add_argument("--png", default=None, help="also write frame FRAME as a PNG to this path")
    p.add_argument("--frame", type=int, default=10, help="frame written by --png")


def _check_outputs(args) -> None:
    """Every output path writable and the seed usable, before the scene is simulated."""
    from harness.io import check_output_file

    for flag in ("out", "truth", "png"):
        if getattr(args, flag, None):
            check_output_file(getattr(args, flag), f"--{flag}")
    if not 0 <= args.seed < 2**63:
        raise HarnessError(f"--seed must be in [0, 2**63), got {args.seed}")


def _motion(args):
    from harness.motion.motion import Motion

    if args.motion:
        return Motion.load(args.motion)
    from harness.motion.performer import demonstrations

    return demonstrations(args.label, 1, np.random.default_rng(args.seed), fps=30.0)[0]


def _spec(args):
    from harness.scene.spec import CameraSpec, MarkerSpec, ObservationSpec, OccluderSpec, SceneSpec

    return SceneSpec(MarkerSpec(args.markers, args.seed),
                     CameraSpec(distance=args.distance, azimuth=args.azimuth, elevation=args.elevation),
                     OccluderSpec(args.preset, args.amount, args.seed),
                     ObservationSpec(mode=args.mode, noise_px=args.noise))


def _simulate_args(p: argparse.ArgumentParser) -> None:
    _args(p)
    p.set_defaults(out="observation.npz")
    p.add_argument("--truth", default=None, help="also write the ground truth (.npz) to this path")


@command("simulate", _simulate_args)
def simulate_command(args: argparse.Namespace) -> int:
    """Write what the scene camera observes (the engine's input, .npz) and optionally the ground truth."""
    from harness.body import BodyModel
    from harness.scene.simulate import simulate

    _check_outputs(args)
    obs, truth = simulate(_motion(args), _spec(args), np.random.default_rng(args.seed), BodyModel.load())
    obs.save(args.out)
    if args.truth:
        truth.save(args.truth)
    print(f"{args.out}: {len(obs)} frames, {int(obs.counts.sum())} flows; obstacle occlusion "
          f"{truth.obstacle_occlusion():.2f}, mean self-occlusion {truth.self_fraction.mean():.2f}")
    return 0


def _video_args(p: argparse.ArgumentParser) -> None:
    _args(p)
    p.add_argument("--raw", action="store_true", help="the camera's images alone, without the flows drawn (with "
                                                      "--mode video: footage to run track-video on)")


@command("scene-video", _video_args)
def scene_video(args: argparse.Namespace) -> int:
    """Video of the scene camera with the observed flows drawn (yellow; red for outliers)."""
    from harness.body import BodyModel
    from harness.scene.rendered import render_frames
    from harness.scene.simulate import OUTLIER_ID, build_setup, simulate
    from harness.video import draw_flows, write_video

    _check_outputs(args)
    motion = _motion(args)
    spec = _spec(args)
    body = BodyModel.load()
    obs, truth = simulate(motion, spec, np.random.default_rng(args.seed), body)
    setup = build_setup(motion, spec, body)
    # Video mode's footage is the cloth itself (no marker dots); --raw leaves the flows off (footage for
    # track-video).
    images = render_frames(setup, motion.qpos, dots=spec.observation.mode != "video")
    frames = [rgb if args.raw else draw_flows(rgb, obs.flows[t], truth.marker_ids[t] == OUTLIER_ID)
              for t, rgb in enumerate(images)]
    if args.png:
        import cv2

        if not 0 <= args.frame < len(frames):
            raise HarnessError(f"--frame={args.frame}: the motion has {len(frames)} frames")
        cv2.imwrite(args.png, cv2.cvtColor(frames[args.frame], cv2.COLOR_RGB2BGR))
    n = write_video(args.out, frames, motion.fps)
    print(f"{args.out}: {n} frames; {int(obs.counts.sum())} flows; obstacle occlusion "
          f"{truth.obstacle_occlusion():.2f}, mean self-occlusion {truth.self_fraction.mean():.2f}")
    return 0
