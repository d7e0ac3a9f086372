"""Learn the classifier from exported runs: ``python -m flowclf.train DATA [DATA ...] --out flowclf/model.npz``.

Each exported run (``harness.evaluation.export``) gives the descriptors of its windows ending at ``FRACTIONS`` of
the clip (so that the method answers sensibly early in a clip too), labelled with the run's class. The model file
holds the standardised descriptors and their labels (``np.savez``, no pickle); ``flowclf.method`` fits the
k-nearest-neighbour classifier on them when it is imported. Only the runs of the exports named are read: export
scenarios whose seeds and subjects are not those the method is scored on (``examples/flowclf/train.yaml``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from flowclf.features import window_descriptors

FRACTIONS = (0.25, 0.5, 0.75, 1.0)      # windows from the start to these fractions of each clip


def training_set(directories) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Descriptors ``(N, D)``, labels ``(N,)`` and the run keys read, from every run of the exports."""
    from harness.evaluation.export import load_runs

    rows, labels, keys = [], [], []
    for directory in directories:
        for run in load_runs(directory):
            if run.labels is not None:
                raise SystemExit(f"{directory}: run {run.key} is a stream; flowclf learns one primitive per run")
            desc = window_descriptors(run.obs.flows)
            for fraction in FRACTIONS:
                row = desc[max(int(round(fraction * len(desc))) - 1, 0)]
                if np.all(np.isfinite(row)):
                    rows.append(row)
                    labels.append(run.label)
            keys.append(f"{directory}:{run.key}")
    if not rows:
        raise SystemExit("no usable run in the exports")
    return np.array(rows), np.array(labels), keys


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m flowclf.train", description=__doc__.splitlines()[0])
    p.add_argument("exports", nargs="+", help="directories written by `harness export`")
    p.add_argument("--out", default=str(Path(__file__).with_name("model.npz")), help="model file (default: the package's)")
    args = p.parse_args(argv)
    x, y, keys = training_set(args.exports)
    mean, std = x.mean(axis=0), x.std(axis=0)
    std[std == 0] = 1.0
    np.savez(args.out, x=(x - mean) / std, y=y, mean=mean, std=std)
    print(f"{args.out}: {len(x)} windows of {len(keys)} runs, classes {', '.join(sorted(set(y)))}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
