"""``harness reproduce``: recognise an observed motion, then reproduce it from the database (mimesis).

    python -m harness reproduce observation.npz --database db.npz --out repro.npz [--video repro.mp4]
        [--truth truth.npz] [--mirror] [--scale 0.8]

The engine runs on the observation; the recognised primitive's HMM generates the motion along the recovered
state path (``harness.engine.reproduction``), in the demonstrator's recovered world frame (z up, on the floor
below its first pelvis position, facing as it faced), performed with the other side (``--mirror``) or by a body
scaled uniformly (``--scale``: a robot's size). Writes the reproduction as a Motion ``.npz`` and, with
``--video``, the observed motion (the true one from ``--truth``, else the recovered one) beside the
reproduction. With ``--truth`` it also prints ``repro_dtw_deg`` and ``repro_dtw_mm`` against the demonstration
and the same for the recognised class's mean trajectory.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from harness.commands import command
from harness.errors import HarnessError


class ReproduceError(HarnessError):
    """Bad arguments to ``reproduce``."""


def _args(p: argparse.ArgumentParser) -> None:
    p.add_argument("observation", help="observation file (.npz)")
    p.add_argument("--database", required=True, help="motion database (.npz)")
    p.add_argument("--out", required=True, help="the reproduction, a Motion (.npz)")
    p.add_argument("--video", default=None, help="observed motion beside the reproduction (.mp4 or .gif)")
    p.add_argument("--truth", default=None, help="ground truth of the observation (.npz): the demonstration, for "
                                                 "the video and the DTW scores")
    p.add_argument("--mirror", action="store_true", help="perform it with the other side")
    p.add_argument("--scale", type=float, default=1.0, help="uniform scale of the reproducing body (default 1)")
    p.add_argument("--particles", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)


@command("reproduce", _args)
def reproduce_command(args: argparse.Namespace) -> int:
    """Recognise an observed motion and reproduce it from the database (another frame, side or body size)."""
    from harness.body import BodyModel
    from harness.engine.database import MotionDatabase
    from harness.engine.reproduction import class_mean, recovered_world, reproduce, state_path
    from harness.engine.config import TrackerConfig
    from harness.engine.tracker import Tracker
    from harness.evaluation.reproduction_metrics import dtw_angle_rms_deg, dtw_mpjpe_mm
    from harness.geometry import heading
    from harness.motion.motion import Motion
    from harness.observation import Observation

    from harness.engine.cli import MAX_DATABASE_BYTES
    from harness.errors import EngineError
    from harness.io import check_output_file, inspect_npz

    if not 0.5 <= args.scale <= 1.5:
        raise ReproduceError(f"--scale must be in [0.5, 1.5], got {args.scale}")
    if args.video is not None and Path(args.video).suffix.lower() not in (".mp4", ".gif"):
        raise ReproduceError(f"--video {args.video}: video files must end in .mp4 or .gif")
    check_output_file(args.out)
    if args.video is not None:
        check_output_file(args.video, "--video")
    if not 0 <= args.seed < 2**63:
        raise ReproduceError(f"--seed must be in [0, 2**63), got {args.seed}")
    config = TrackerConfig.from_dict({"tracks": {"particles": args.particles}})
    obs = Observation.load(args.observation)
    inspect_npz(args.database, EngineError, "database", MAX_DATABASE_BYTES)
    db = MotionDatabase.load(args.database)
    truth = None
    if args.truth is not None:
        from harness.scene.simulate import GroundTruth

        truth = GroundTruth.load(args.truth)
        if len(truth.qpos) != len(obs):
            raise ReproduceError(f"--truth {args.truth}: {len(truth.qpos)} frames, the observation has {len(obs)}")
    nominal = BodyModel.load()
    body = nominal if args.scale == 1.0 else nominal.scaled(np.where(np.arange(nominal.model.nbody) > 0,
                                                                      args.scale, 1.0))
    if obs.counts.sum() == 0:
        raise ReproduceError(f"{args.observation}: no frame has any flow: nothing to recognise")
    est = Tracker(db, nominal, config, np.random.default_rng(args.seed)).run(obs)
    label = est.predicted
    world = recovered_world(nominal, est.qpos, None if obs.gravity is None else obs.gravity[0])
    repro = reproduce(db, body, label, state_path(db, est.joint_posterior, label), obs.fps,
                      start_heading=float(heading(world[0, 3:7])),
                      mirror=args.mirror, angles=est.qpos[:, 7:])
    repro = repro.replace(source=repro.source + (f", body scaled {args.scale:g}" if args.scale != 1.0 else ""))
    repro.save(args.out)
    print(f"{args.out}: {label} reproduced over {repro.n_frames} frames ({repro.source})")
    if truth is not None:
        demo = truth.qpos
        mean = class_mean(db, nominal, label, len(demo), obs.fps)
        print(f"repro_dtw_deg {dtw_angle_rms_deg(repro.angles, demo[:, 7:]):.2f}  "
              f"repro_dtw_mm {dtw_mpjpe_mm(body, repro.qpos, nominal, demo):.1f}  (class mean of {label}: "
              f"{dtw_angle_rms_deg(mean.angles, demo[:, 7:]):.2f} deg, {dtw_mpjpe_mm(nominal, mean.qpos, nominal, demo):.1f} mm)")
    if args.video is not None:
        from harness.video import render_motion, write_video

        observed = Motion(truth.qpos if truth is not None else world, obs.fps, label)
        left = render_motion(nominal.model, observed.qpos, width=360, height=360)
        right = render_motion(body.model, repro.qpos, width=360, height=360)
        n = write_video(args.video, (np.concatenate([a, b], axis=1) for a, b in zip(left, right)), obs.fps)
        print(f"{args.video}: {n} frames, observed ({'true' if truth is not None else 'recovered'}) left, "
              f"reproduction right")
    return 0
