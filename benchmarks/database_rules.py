"""How the database's training rule biases recognition on real captures: joint-space recognition (the
``joint_space`` method, exactly) under alternative rules, on the capture scenarios' own splits.

Run: ``python benchmarks/database_rules.py [DIR] [--rules A,B] [--outliers E,F] [--states K ...]
[--scenarios S,T]`` (DIR defaults to ``../shared/mocap/cmu``). For every run of ``scenarios/sim2real.yaml``,
``sim2real_mixed.yaml`` and both conditions of ``mocap.yaml`` (leave-one-out, cross-subject), the database is trained on what the pipeline trains it on
(``pipeline.training_motions``) under each rule, and the test capture is recognised from its true joint-space
features. Accuracy over all runs, then over the development demonstrations (the performer's calibration
demonstrations, ``realism.calibration_split``: what settings are chosen on) and the report demonstrations
apart; per class; and the classes answered for wrong ones. ``--outliers``: the emissions' per-feature outlier
shares to compare (``MotionDatabase.log_emissions``; 0 is the plain Gaussian, the default is the method's),
each scored over the capture's measured features as the method does. ``--states``: the HMM states per
primitive (a side) to compare (default the database's 20). ``--adapt``: standard deviations (rad) of a posture
offset per class and capture to compare (``adapted_log_likelihoods``; 0, the default, is the method's scoring).

Rules (``RULES``): ``group`` (the feature groups' floors alone, as before issue 24), ``human`` (the human floor
at ``FLOOR_SCALE``, the default), ``human<s>`` (at scale ``s``), ``human-rates`` (the human floor on the rates and the base's velocities only), ``balanced`` (the human floor, and every class
trained on as many demonstrations as the class with the fewest, taken round-robin over subjects), ``tempo`` (the human
floor, and every capture also played 0.8 and 1.25 times as fast, ``tempo_copies``),
``offset-group`` / ``offset-human`` (sim2real only: per-class log-likelihood offsets per frame fitted on the
development captures, ``fit_offsets``). One-class databases are cached by class, rule and training motions (and the
whole training set, for a class with features none of its demonstrations measures: their population), so a
leave-one-out database costs about one class's fit.
"""

import argparse
import itertools
import sys
import time
from collections import Counter, defaultdict
from pathlib import Path

import numpy as np
from scipy.optimize import minimize
from scipy.special import log_softmax, logsumexp

from harness.engine import MotionDatabase, motion_features, recognize_features
from harness.engine.database import DEFAULT_STATES
from harness.engine.features import ANGLES, measured_features
from harness.engine.recognition import FEATURE_OUTLIER
from harness.engine.variance_floor import FLOOR_SCALE, HUMAN_FLOOR_PATH, group_floor, read_human_floor
from harness.evaluation.pipeline import test_motion, training_identity, training_motions
from harness.evaluation.runner import plan
from harness.evaluation.loading import load_scenario
from harness.evaluation.scenario_captures import resolve_capture
from harness.motion.performer import CYCLIC
from harness.motion.realism import calibration_split

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_DIR = ROOT.parent / "shared" / "mocap" / "cmu"
SCENARIOS = {"sim2real": "sim2real.yaml", "mixed": "sim2real_mixed.yaml", "mocap": "mocap.yaml"}
SCALES = (1.0, 2.0, 4.0, 8.0)
TEMPO_FACTORS = (0.8, 1.25)


def floor_at(scale: float) -> np.ndarray:
    return np.maximum(group_floor(), scale * read_human_floor(HUMAN_FLOOR_PATH))


def balanced(motions):
    """Every class cut to the smallest class's number of demonstrations, taken round-robin over its subjects
    (each subject's in their order)."""
    by_class = defaultdict(list)
    for m in motions:
        by_class[m.label].append(m)
    n = min(len(v) for v in by_class.values())
    out = []
    for ms in by_class.values():
        queues = defaultdict(list)
        for m in ms:
            queues[m.subject].append(m)
        order = [q[i] for i in range(max(map(len, queues.values()))) for q in queues.values() if i < len(q)]
        out += order[:n]
    return out


def tempo_copies(motions, factors=TEMPO_FACTORS):
    """Every captured demonstration also at each tempo of ``factors`` (played that many times faster,
    ``Motion.resample`` then the original frame rate): a style-free spread of speeds for cross-subject
    recognition to learn from. Procedural demonstrations are left as they are (the performer varies tempo)."""
    return list(motions) + [m.resample(m.fps / s).replace(fps=m.fps, demo=f"{m.demo}@{s:g}")
                            for m in motions if m.source != "procedural" for s in factors]


def rates_only(scale: float) -> np.ndarray:
    """The human floor on the angle rates and the base's velocities only; the angles keep the group floor."""
    floor = floor_at(scale)
    floor[ANGLES] = group_floor()[ANGLES]
    return floor


RULES = {"group": (group_floor, None), "human": (lambda: floor_at(FLOOR_SCALE), None),
         "human-rates": (lambda: rates_only(FLOOR_SCALE), None),
         "balanced": (lambda: floor_at(FLOOR_SCALE), balanced),
         "tempo": (lambda: floor_at(FLOOR_SCALE), tempo_copies)} | {
    f"human{s:g}": ((lambda s=s: floor_at(s)), None) for s in SCALES}


class Databases:
    """Databases of a rule from one-class fits, each made once."""

    def __init__(self, rule: str, n_states: int = DEFAULT_STATES):
        self.n_states = n_states
        self.floor, self.select = RULES[rule.removeprefix("offset-")]
        self.floor = self.floor()
        self.fits = {}

    def __call__(self, training) -> MotionDatabase:
        if self.select is not None:
            training = self.select(training)
        parts = []
        for label in sorted({m.label for m in training}):
            own = [m for m in training if m.label == label]
            # The whole training set is the population of the features the class never measures (if any).
            unmeasured = not np.any([measured_features(m) for m in own], axis=0).all()
            key = (label, tuple(sorted(str(training_identity(m)) for m in own)),
                   tuple(sorted(str(training_identity(m)) for m in training)) if unmeasured else ())
            if key not in self.fits:
                self.fits[key] = MotionDatabase(self.n_states, cyclic=CYCLIC, floor=self.floor).fit(
                    own, population=training)
            parts.append(self.fits[key])
        return stack(parts)


def stack(parts: list[MotionDatabase]) -> MotionDatabase:
    """One database of the classes of one-class databases trained alike."""
    first = parts[0]
    db = MotionDatabase(first.n_states, first.cyclic, first.n_iter, first.mirrored, first.floor)
    db.classes_ = np.concatenate([p.classes_ for p in parts])
    db.cyclic_ = np.isin(db.classes_, list(db.cyclic))
    for name in ("means_", "covars_", "transmat_", "startprob_"):
        setattr(db, name, np.concatenate([getattr(p, name) for p in parts]))
    db.fps_ = first.fps_
    return db


def log_likelihoods(db: MotionDatabase, motion, outlier: float) -> np.ndarray:
    """``(C,)`` the recursion's final log posterior (uniform prior: the class log-likelihoods up to a constant),
    the emissions with the per-feature ``outlier`` share over the capture's measured features."""
    post = recognize_features(db, motion_features(motion), outlier=outlier, measured=measured_features(motion))[-1]
    return np.log(np.maximum(post, 1e-300))


def forward_backward(log_b: np.ndarray, log_start: np.ndarray, log_trans: np.ndarray) -> tuple[float, np.ndarray]:
    """One HMM's log-likelihood of emissions ``log_b`` ``(T, S)`` and its state occupancies ``(T, S)``."""
    T, S = log_b.shape
    log_alpha, log_beta = np.empty((T, S)), np.zeros((T, S))
    log_alpha[0] = log_start + log_b[0]
    for t in range(1, T):
        log_alpha[t] = logsumexp(log_alpha[t - 1][:, None] + log_trans, axis=0) + log_b[t]
    for t in range(T - 2, -1, -1):
        log_beta[t] = logsumexp(log_trans + (log_b[t + 1] + log_beta[t + 1])[None], axis=1)
    ll = logsumexp(log_alpha[-1])
    return float(ll), np.exp(log_alpha + log_beta - ll)


def adapted_log_likelihoods(db: MotionDatabase, features: np.ndarray, measured: np.ndarray, outlier: float,
                            sigma: float, start_spread: float = 0.05, iterations: int = 4) -> np.ndarray:
    """``(C,)`` each class's log-likelihood of a capture whose measured angles the class explains up to a constant
    posture offset ``delta ~ N(0, sigma^2 I)`` (a performer's style; bias adaptation, as of a speaker in speech
    recognition): ``delta`` by EM (the occupancies, then the Gaussian MAP step), the offset integrated out by
    Laplace's method, ``log p(f - delta | c) + log N(delta; 0, sigma^2) + 1/2 log det(2 pi H^-1)``, ``H`` the
    offset's posterior precision. Exact for one state and Gaussian emissions (``outlier`` 0). ``sigma`` 0: the
    class log-likelihoods without an offset (the recursion's start as ``Recognizer``'s)."""
    C, S = db.startprob_.shape
    with np.errstate(divide="ignore"):
        log_start = np.log((1 - start_spread) * db.startprob_ + start_spread / S)
        log_trans = np.log(db.transmat_)
    adapt = np.zeros(features.shape[1], dtype=bool)
    adapt[ANGLES] = True
    adapt &= measured
    base = db.log_emissions(features, outlier=outlier, measured=measured)
    out = np.empty(C)
    for c in range(C):
        log_b, delta = base[:, c], np.zeros(features.shape[1])
        mean, var = db.means_[c][:, adapt], db.covars_[c][:, adapt]
        for _ in range(iterations if sigma > 0 else 0):
            _, gamma = forward_backward(log_b, log_start[c], log_trans[c])
            residual = np.einsum("ts,tsj->j", gamma, (features[:, None, adapt] - mean[None]) / var[None])
            delta[adapt] = residual / (gamma.sum(0) @ (1.0 / var) + sigma**-2.0)
            log_b = db.log_emissions(features - delta, outlier=outlier, measured=measured)[:, c]
        ll, gamma = forward_backward(log_b, log_start[c], log_trans[c])
        if sigma > 0:
            precision = gamma.sum(0) @ (1.0 / var) + sigma**-2.0
            ll -= 0.5 * np.sum(delta[adapt] ** 2) / sigma**2 + 0.5 * np.sum(np.log(sigma**2 * precision))
        out[c] = ll
    return out


def fit_offsets(scores: np.ndarray, frames: np.ndarray, labels: np.ndarray, classes) -> np.ndarray:
    """Per-class offsets ``o`` (nats per frame, mean 0) that maximise the held-out class log-likelihood
    ``sum_n log softmax_c(L_nc - o_c T_n)[y_n]`` (convex in ``o``)."""
    y = np.array([list(classes).index(lbl) for lbl in labels])

    def loss(o):
        z = scores - np.outer(frames, o - o.mean())
        return -log_softmax(z, axis=1)[np.arange(len(y)), y].sum()

    o = minimize(loss, np.zeros(len(classes)), method="Powell").x
    return o - o.mean()


def scenario(name: str, capture_dir: str):
    return resolve_capture(load_scenario(ROOT / "scenarios" / SCENARIOS[name]), capture_dir)


def evaluate(scenario_name: str, rule: str, capture_dir: str, development: set[str],
             outliers: tuple[float, ...] = (FEATURE_OUTLIER,), n_states: int = DEFAULT_STATES,
             adapt: tuple[float, ...] = (0.0,)) -> dict[tuple[float, float], list[dict]]:
    """Rows of every run by (outlier share, offset sd)."""
    dbs = Databases(rule, n_states)
    rows = {key: [] for key in itertools.product(outliers, adapt)}
    for run in plan(scenario(scenario_name, capture_dir), "/nonexistent"):
        motion = test_motion(run)
        db = dbs(training_motions(run.config, motion))
        for eps, sigma in rows:
            scores = (log_likelihoods(db, motion, eps) if sigma == 0 else adapted_log_likelihoods(
                db, motion_features(motion), measured_features(motion), eps, sigma))
            rows[eps, sigma].append({"condition": f"{scenario_name}/{run.condition_label}", "label": motion.label,
                                     "dev": motion.demo + motion.label in development, "classes": db.classes_,
                                     "scores": scores, "frames": motion.n_frames})
    for (eps, _), rs in rows.items():
        if rule.startswith("offset-"):
            dev = [r for r in rs if r["dev"]]
            o = fit_offsets(np.array([r["scores"] for r in dev]), np.array([r["frames"] for r in dev]),
                            np.array([r["label"] for r in dev]), dev[0]["classes"])
            print(f"  offsets (nats/frame, outlier {eps:g}): {dict(zip(dev[0]['classes'], np.round(o, 2)))}")
            for r in rs:
                r["scores"] = r["scores"] - o * r["frames"]
        for r in rs:
            r["answer"] = str(r["classes"][np.argmax(r["scores"])])
    return rows


def summary(rows: list[dict]) -> str:
    acc = lambda rs: f"{100 * np.mean([r['answer'] == r['label'] for r in rs]):5.1f}% ({len(rs)})" if rs else "-"  # noqa: E731
    per = defaultdict(list)
    for r in rows:
        per[r["label"]].append(r["answer"] == r["label"])
    wrong = Counter(r["answer"] for r in rows if r["answer"] != r["label"])
    return (f"all {acc(rows)}  development {acc([r for r in rows if r['dev']])}  report "
            f"{acc([r for r in rows if not r['dev']])}\n      per class "
            + " ".join(f"{c}:{sum(v)}/{len(v)}" for c, v in sorted(per.items()))
            + "\n      answered when wrong: " + ", ".join(f"{c} {n}" for c, n in wrong.most_common(4)))


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("directory", nargs="?", default=str(DEFAULT_DIR))
    parser.add_argument("--rules", default="group,human", help="comma-separated, of: " + ", ".join(RULES)
                        + ", offset-group, offset-human")
    parser.add_argument("--outliers", default=str(FEATURE_OUTLIER),
                        help="comma-separated per-feature outlier shares of the emissions (0: plain Gaussian)")
    parser.add_argument("--states", type=int, nargs="+", default=[DEFAULT_STATES],
                        help="HMM states per primitive (per side) to compare")
    parser.add_argument("--scenarios", default="sim2real,mixed,mocap", help="of: " + ", ".join(SCENARIOS))
    parser.add_argument("--adapt", default="0", help="comma-separated sds (rad) of a posture offset per class and "
                        "capture (0: none, the method)")
    args = parser.parse_args()
    # The capture scenario's training set without a test motion is every capture (retargeted once, cached).
    captures = training_motions(scenario("mocap", args.directory), None)
    development = {m.demo + m.label for m in calibration_split(captures)[0]}
    outliers = tuple(float(x) for x in args.outliers.split(","))
    adapt = tuple(float(x) for x in args.adapt.split(","))
    for rule, states in itertools.product(args.rules.split(","), args.states):
        for name in args.scenarios.split(","):
            if rule.startswith("offset-") and name != "sim2real":
                continue
            t0 = time.perf_counter()
            for (eps, sigma), rows in evaluate(name, rule, args.directory, development, outliers, states,
                                               adapt).items():
                for cond in dict.fromkeys(r["condition"] for r in rows):
                    offset = f" offset sd {sigma:g}" if sigma else ""
                    print(f"{rule:10} K={states:<3} {eps:<5g}{offset} {cond:28} "
                          f"{summary([r for r in rows if r['condition'] == cond])}")
            print(f"  ({time.perf_counter() - t0:.0f} s)", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
