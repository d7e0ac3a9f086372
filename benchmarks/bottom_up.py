"""Does retraining the bottom-up estimator reproduce the shipped model's scores? (issue 61)

Regenerates the training data with the shipped model's recipe (its clips, seed and capture share, from the
model file's ``info``), retrains it, and prints the held-out scores of both beside each other; with
``--test-clips N`` both are also scored on N fresh clips of another seed (``--test-seed``), which neither saw.
Exits non-zero when a retrained score is off the shipped one by more than the tolerance (``TOLERANCE``:
relative, the run-to-run spread of scikit-learn's fit on a different CPU is a few per cent).

    python benchmarks/bottom_up.py [--clips N] [--jobs 2] [--test-clips 300] [--out retrained.npz]
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from harness.engine.bottom_up import BottomUpModel
from harness.posture.data import make_dataset
from harness.posture.train import fit, scores

TOLERANCE = 0.10            # relative difference of a retrained score from the shipped model's
COMPARED = ("rotation_deg", "heading_deg", "angles_rms_rad", "rates_rms_rad_s", "base_velocity_rms",
            "depth_rel_median")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--clips", type=int, default=None, help="clips (default: the shipped model's)")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--test-clips", type=int, default=0, help="also score both on this many fresh clips")
    p.add_argument("--test-seed", type=int, default=6161)
    p.add_argument("--out", default=None, help="write the retrained model here")
    args = p.parse_args(argv)

    shipped = BottomUpModel.load()
    info = json.loads(shipped.info)
    clips = args.clips or info["clips"]
    t0 = time.perf_counter()
    x, y, c = make_dataset(info["seed"], clips, capture_share=info["capture_share"], jobs=args.jobs)
    simulated = time.perf_counter() - t0
    model, retrained = fit(x, y, c, seed=info["seed"], info={"clips": clips, "seed": info["seed"],
                                                             "capture_share": info["capture_share"]})
    if args.out:
        np.savez(args.out, **model.to_arrays())
    print(f"{len(x)} windows of {clips} clips, simulated in {simulated:.0f} s, fitted in {retrained['train_s']} s")
    print(f"{'score':22s} {'shipped':>10s} {'retrained':>10s}")
    failed = []
    for k in COMPARED:
        a, b = info["scores"][k], retrained[k]
        ok = abs(b - a) <= TOLERANCE * abs(a)
        failed += [] if ok else [k]
        print(f"{k:22s} {a:10.4g} {b:10.4g} {'' if ok else '  <- off by more than the tolerance'}")
    if args.test_clips:
        xt, yt, _ = make_dataset(args.test_seed, args.test_clips, capture_share=info["capture_share"],
                                 jobs=args.jobs)
        a, b = scores(shipped, xt, yt), scores(model, xt, yt)
        print(f"fresh clips (seed {args.test_seed}, {args.test_clips} clips, {len(xt)} windows):")
        for k in COMPARED + ("angles_z2",):
            print(f"{k:22s} {a[k]:10.4g} {b[k]:10.4g}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
