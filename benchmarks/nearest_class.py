"""Nearest-class check of the procedural performer (``harness.motion.nearest_class``): prints the 10x10
confusion matrix and the accuracy; exits 1 outside the requirement (at least ``MIN_ACCURACY``, below 1: separable
but not trivially so; docs/performer.md).

Run: ``python benchmarks/nearest_class.py [--train 8 --test 10 --train-seed 1 --test-seed 2]``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

from harness.motion.nearest_class import (MIN_ACCURACY, TEST_SUBJECTS, TRAIN_SUBJECTS, format_confusion, make_set,
                                          nearest_class)
from harness.motion.performer import CLASSES


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--train", type=int, default=8, help="training demonstrations per class")
    p.add_argument("--test", type=int, default=10, help="held-out demonstrations per class")
    p.add_argument("--train-seed", type=int, default=1)
    p.add_argument("--test-seed", type=int, default=2)
    args = p.parse_args(argv)
    t0 = time.perf_counter()
    train = make_set(args.train_seed, args.train, TRAIN_SUBJECTS)
    test = make_set(args.test_seed, args.test, TEST_SUBJECTS)
    confusion, acc = nearest_class(train, test)
    print(format_confusion(confusion))
    off = confusion - np.diag(np.diag(confusion))
    pairs = sorted(((off[i, j] + off[j, i], CLASSES[i], CLASSES[j]) for i in range(len(CLASSES))
                    for j in range(i + 1, len(CLASSES))), reverse=True)
    print("most confused pairs: " + ", ".join(f"{a}/{b} {n}" for n, a, b in pairs[:4] if n))
    print(f"accuracy {acc:.3f} on {len(test)} held-out demonstrations (chance {1 / len(CLASSES):.2f}); "
          f"{args.train} training demos per class; {time.perf_counter() - t0:.1f} s")
    ok = MIN_ACCURACY <= acc < 1.0
    print(f"{'PASS' if ok else 'FAIL'}: requirement {MIN_ACCURACY} <= accuracy < 1")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
