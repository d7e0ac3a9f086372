"""Commands of the engine: learn a database, track a saved observation file.

    python -m harness train-database --out db.npz [--classes walk run ...] [--demos 8] [--states 20]
    python -m harness track observation.npz --database db.npz [--out estimate.npz]
"""

from __future__ import annotations

import argparse

import numpy as np

from harness.commands import command
from harness.errors import EngineError
from harness.io import save_npz_atomic

MAX_DATABASE_BYTES = 1 << 30     # a database file, and what its arrays expand to (the default one is 2 MB)


def _check_seed(seed: int) -> None:
    if not 0 <= seed < 2**63:
        raise EngineError(f"--seed must be in [0, 2**63), got {seed}")


def _train_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", required=True, help="database file to write (.npz)")
    p.add_argument("--classes", nargs="*", default=None, help="procedural primitives (default: all ten)")
    p.add_argument("--demos", type=int, default=8, help="demonstrations per class (one subject each)")
    p.add_argument("--states", type=int, default=20, help="HMM states per primitive (per side)")
    p.add_argument("--one-sided", action="store_true",
                   help="without the mirror-image chains (the demonstrations' sides only)")
    p.add_argument("--seed", type=int, default=0, help="training seed")
    p.add_argument("--fps", type=float, default=30.0)
    p.add_argument("--capture-dir", default=None, help="learn from a capture set (directory with MANIFEST.csv) "
                                                       "instead of the procedural performer")


@command("train-database", _train_args)
def train_database(args: argparse.Namespace) -> int:
    """Learn the motion database (one HMM per primitive) and write it as .npz."""
    from harness.engine.database import MotionDatabase
    from harness.io import check_output_file
    from harness.motion.performer import CYCLIC

    check_output_file(args.out)                 # before the training, not after it
    _check_seed(args.seed)
    if args.capture_dir:
        from harness.motion.captures import load_capture_set

        motions = load_capture_set(args.capture_dir, fps=args.fps, classes=args.classes)
    else:
        from harness.motion.performer import CLASSES, training_set

        motions = training_set(args.classes or CLASSES, args.demos, args.seed, args.fps)
    db = MotionDatabase(n_states=args.states, cyclic=CYCLIC, mirrored=not args.one_sided).fit(motions)
    db.save(args.out)
    sides = "one side" if args.one_sided else "both sides"
    print(f"{args.out}: {len(db.classes_)} primitives x {args.states} states x {sides} from {len(motions)} "
          "demonstrations")
    return 0


def _track_args(p: argparse.ArgumentParser) -> None:
    p.add_argument("observation", help="observation file (.npz, format in harness/observation.py)")
    p.add_argument("--database", required=True, help="motion database (.npz) from train-database")
    p.add_argument("--out", default=None, help="write the estimate (.npz): qpos (T, 57) in the camera frame, "
                                              "class posteriors (T, C), classes")
    p.add_argument("--particles", type=int, default=200)
    p.add_argument("--seed", type=int, default=0)


@command("track", _track_args)
def track(args: argparse.Namespace) -> int:
    """Run the engine on a saved observation: recognised primitive per frame, recovered 56-DOF trajectory."""
    from harness.body import BodyModel
    from harness.engine.database import MotionDatabase
    from harness.engine.config import TrackerConfig
    from harness.engine.tracker import Tracker
    from harness.io import check_output_file, inspect_npz
    from harness.observation import Observation

    if args.out is not None:
        check_output_file(args.out)             # before the tracking, not after it
    _check_seed(args.seed)
    config = TrackerConfig.from_dict({"tracks": {"particles": args.particles}})
    obs = Observation.load(args.observation)
    inspect_npz(args.database, EngineError, "database", MAX_DATABASE_BYTES)
    db = MotionDatabase.load(args.database)
    if abs(db.fps_ - obs.fps) > 1e-6:
        raise EngineError(f"{args.observation}: observed at {obs.fps:g} fps but the database was learned at "
                          f"{db.fps_:g} fps")
    if obs.counts.sum() == 0:       # before the engine is built: its error would name no file
        raise EngineError(f"{args.observation}: no frame has any flow: nothing to estimate")
    est = Tracker(db, BodyModel.load(), config, np.random.default_rng(args.seed)).run(obs)
    top = np.argsort(est.class_posterior[-1])[::-1][:3]
    print(f"{args.observation}: {len(obs)} frames, {est.ms_per_frame.mean():.1f} ms/frame; recognised "
          + ", ".join(f"{est.classes[i]} {est.class_posterior[-1, i]:.2f}" for i in top))
    if args.out:
        save_npz_atomic(args.out, {"classes": est.classes.astype(str), "qpos": est.qpos,
                                   "class_posterior": est.class_posterior, "filter_pos": est.filter_pos,
                                   "filter_quat": est.filter_quat, "ms_per_frame": est.ms_per_frame})
    return 0
