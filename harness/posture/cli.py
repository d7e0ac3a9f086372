"""``harness train-posture``: regenerate the bottom-up estimator's training data and retrain it."""

from __future__ import annotations

import argparse

from harness.commands import command

DEFAULT_CLIPS = 2500
DEFAULT_SEED = 61           # the number: no scenario, development or reported, uses it


def _args(p: argparse.ArgumentParser) -> None:
    from harness.engine.bottom_up import MODEL_PATH

    p.add_argument("--clips", type=int, default=DEFAULT_CLIPS, help=f"simulated clips (default {DEFAULT_CLIPS})")
    p.add_argument("--seed", type=int, default=DEFAULT_SEED, help=f"the data set's and the fit's seed "
                                                                  f"(default {DEFAULT_SEED})")
    p.add_argument("--capture-share", type=float, default=0.25,
                   help="share of clips from the capture library's development groups (default 0.25)")
    p.add_argument("--jobs", type=int, default=1, help="processes that simulate (default 1)")
    p.add_argument("--out", default=str(MODEL_PATH), help=f"model file (default {MODEL_PATH})")


@command("train-posture", _args)
def train_posture(args: argparse.Namespace) -> int:
    """Simulate the training clips, fit the bottom-up estimator and write it as .npz; prints its held-out
    scores."""
    import json
    import time

    from harness.errors import HarnessError
    from harness.io import save_npz_atomic
    from harness.posture.data import make_dataset
    from harness.posture.train import fit

    if args.clips < 10 or args.seed < 0 or not 0 <= args.capture_share <= 1 or args.jobs < 1:
        raise HarnessError(f"train-posture: --clips >= 10, --seed >= 0, --capture-share in [0, 1], --jobs >= 1; "
                           f"got {args.clips}, {args.seed}, {args.capture_share}, {args.jobs}")
    t0 = time.perf_counter()
    x, y, clips = make_dataset(args.seed, args.clips, capture_share=args.capture_share, jobs=args.jobs)
    simulated = time.perf_counter() - t0
    model, scores = fit(x, y, clips, seed=args.seed,
                        info={"clips": args.clips, "seed": args.seed, "capture_share": args.capture_share})
    save_npz_atomic(args.out, model.to_arrays())
    print(f"{args.out}: {len(x)} windows of {args.clips} clips (simulated in {simulated:.0f} s)")
    print(json.dumps(scores, sort_keys=True))
    return 0
