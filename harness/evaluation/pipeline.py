"""One evaluation run: train (or load) the database, play the test motion in the scene, run every method of
the scenario (``harness.evaluation.methods``), score it against the ground truth.
``run_one(RunSpec) -> list[dict]``, one row per method.

Random streams per run (all from the run's seed): the test motion, the scene (markers, azimuth, subject,
noise), and the engine's particle filter, so that adding a method never changes another method's numbers.

Nothing is kept between runs but caches by value, whose entries are never changed: the body model, capture
sets (by directory, manifest and frame rate), databases (by their cache key) and engine prototypes (by
database and ``TrackerConfig``). Each run gets its own engine: a shallow copy of the prototype with the run's
random stream (``Tracker.reset`` builds all per-sequence state anew on the copy), so runs in one process give
the rows they give alone, in any order (tested).
"""

from __future__ import annotations

import copy
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from harness.body import BodyModel
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.engine.database import CYCLIC_PRIMITIVES
from harness.evaluation.cache import cached, path_for_key
from harness.evaluation.methods import METHODS, RunInputs, segment_list
from harness.evaluation.runner import RunError, RunSpec
from harness.evaluation.scenario import Scenario, scene_spec, tracker_config
from harness.evaluation.viewing import viewing_columns
from harness.motion import Motion
from harness.motion.performer import demonstrations, training_set
from harness.motion.stream import TRANSITION, Stream, capture_stream, procedural_stream
from harness.observation import Observation
from harness.scene.simulate import GroundTruth, simulate
from harness.streams import named_stream
from harness.version import code_version

TEST_SUBJECT_OFFSET = 1000                         # held-out procedural demos use subjects never used in training
DATABASE_FORMAT = 1


@lru_cache(maxsize=1)
def nominal_body() -> BodyModel:
    return BodyModel.load()


# --- motions --------------------------------------------------------------------------------------------

@lru_cache(maxsize=4)
def _capture_set(capture_dir: str, manifest: str, fps: float) -> tuple[tuple, tuple[Motion, ...]]:
    """Manifest rows and one retargeted motion per row, in manifest order."""
    from harness.motion.captures import read_manifest, retarget_rows

    rows = read_manifest(Path(capture_dir) / manifest)
    return tuple(rows), tuple(m for m, _ in retarget_rows(capture_dir, rows, fps, nominal_body()))


def _captures(cfg: Scenario) -> tuple[tuple, tuple[Motion, ...]]:
    return _capture_set(str(cfg.database.capture_dir), cfg.database.manifest, float(cfg.database.fps))


@lru_cache(maxsize=2)
def _capture_stream(capture_dir: str, manifest: str, take: str, fps: float) -> Stream:
    return capture_stream(capture_dir, take, Path(capture_dir) / manifest, fps, nominal_body())


def test_stream(run: RunSpec) -> Stream | None:
    """The run's test stream (``test.stream``: a procedural stream by a held-out subject, or a capture take), or
    None for a run of one primitive."""
    cfg = run.config
    stream = cfg.test.stream
    if stream is None:
        return None
    if stream.takes is not None:
        return _capture_stream(str(cfg.database.capture_dir), cfg.database.manifest, stream.takes[run.test_demo],
                               float(cfg.database.fps))
    return procedural_stream(named_stream(run.seed, "motion"), classes=cfg.classes, primitives=stream.primitives,
                             transition_s=stream.transition_s, fps=cfg.database.fps,
                             subject=TEST_SUBJECT_OFFSET + run.test_demo, body=nominal_body(),
                             demo=str(run.test_demo))


def test_motion(run: RunSpec) -> Motion:
    """The run's test motion as the nominal body performs it (the scene plays it on the scenario's subject)."""
    cfg = run.config
    if cfg.test.stream is not None:
        return test_stream(run).motion
    if cfg.database.source == "capture" or cfg.test.split == "captures":
        from harness.motion.captures import demos_by_class

        rows, motions = _captures(cfg)
        demos = demos_by_class(list(rows)).get(run.test_class, [])
        if run.test_demo >= len(demos):
            raise RunError(f"run {run.key}: class {run.test_class!r} has {len(demos)} capture demos")
        return motions[demos[run.test_demo]]
    return demonstrations(run.test_class, 1, named_stream(run.seed, "motion"), fps=cfg.database.fps,
                          subject=TEST_SUBJECT_OFFSET + run.test_demo, body=nominal_body())[0]


def training_motions(cfg: Scenario, test: Motion | None) -> list[Motion]:
    """Procedural: ``performer.training_set``, plus (with ``database.with_captures``) every capture demo of
    another subject than the test motion's. Capture: every manifest demo of the scenario's classes except the
    test demo (leave_one_out) or except the test subject's demos (cross_subject); for a capture stream,
    except every row of its take."""
    db = cfg.database
    if db.source == "capture":
        motions = [m for m in _captures(cfg)[1] if m.label in cfg.classes]
        if test is not None and cfg.test.stream is not None:
            # A capture stream is a whole take: none of its rows trains the database.
            take = test.demo.split(":")[0]
            motions = [m for m in motions if m.demo.split(":")[0] != take]
        elif test is not None and cfg.test.split == "leave_one_out":
            motions = [m for m in motions if not (m.demo == test.demo and m.label == test.label)]
        elif test is not None and cfg.test.split == "cross_subject":
            motions = [m for m in motions if m.subject != test.subject]
        return motions
    out = training_set(cfg.classes, db.train_demos, db.seed, db.fps, body=nominal_body())
    if db.with_captures:
        out += [m for m in _captures(cfg)[1]
                if m.label in cfg.classes and (test is None or m.subject != test.subject)]
    return out


def database_key(cfg: Scenario, test: Motion | None) -> dict:
    """What a database depends on (its cache key), the code version included."""
    db = cfg.database
    key = {"source": db.source, "classes": list(cfg.classes), "states": db.states, "fps": db.fps,
           "cyclic": list(CYCLIC_PRIMITIVES), "format": DATABASE_FORMAT, "code": code_version()}
    if db.source == "procedural":
        key |= {"train_demos": db.train_demos, "seed": db.seed}
        if db.with_captures:
            key |= {"capture_dir": str(db.capture_dir), "manifest": db.manifest,
                    "with_captures_without_subject": None if test is None else test.subject}
    else:
        # Cross-subject databases depend on the test subject only: one per subject, not one per demo.
        without = [] if test is None else ([test.subject] if cfg.test.split == "cross_subject"
                                           else [test.label, test.demo, test.subject])
        key |= {"capture_dir": str(db.capture_dir), "manifest": db.manifest, "split": cfg.test.split,
                "without": without}
    return key


@lru_cache(maxsize=8)
def _stored_database(path: str) -> MotionDatabase:
    return MotionDatabase.load(path)


def database(cfg: Scenario, test: Motion | None, cache_dir: str | Path) -> tuple[MotionDatabase, str]:
    """The run's database (trained once per distinct key, cached on disk) and its cache path."""
    path = path_for_key(Path(cache_dir) / "databases", database_key(cfg, test))

    def build():
        return MotionDatabase(n_states=cfg.database.states, cyclic=CYCLIC_PRIMITIVES).fit(training_motions(cfg, test))

    cached(path, build, lambda obj, fh: np.savez(fh, **obj.to_arrays()), lambda p: None)
    return _stored_database(str(path)), str(path)


@lru_cache(maxsize=4)
def _prototype(database_path: str, config: TrackerConfig) -> Tracker:
    """An engine for this database and configuration (its database transform is the costly part)."""
    return Tracker(_stored_database(database_path), nominal_body(), config)


def fresh_tracker(database_path: str, config: TrackerConfig, rng: np.random.Generator) -> Tracker:
    """A tracker of its own for one run: a copy of the cached prototype with ``rng`` (the prototype is never
    changed; ``Tracker.reset`` creates the filter and recogniser on the copy)."""
    tracker = copy.copy(_prototype(database_path, config))
    tracker.rng = rng
    return tracker


def clear_caches() -> None:
    """Forget every cached value (tests use it to run a run as if alone in a new process)."""
    for f in (nominal_body, _capture_set, _capture_stream, _stored_database, _prototype):
        f.cache_clear()


# --- one run --------------------------------------------------------------------------------------------

def simulate_run(run: RunSpec, motion: Motion | None = None
                 ) -> tuple[Motion, Observation, GroundTruth, BodyModel]:
    """The run's scene, deterministically from its seed: the observed motion (as the subject performed it),
    the observation, the ground truth and the subject's body. ``motion``: the run's test motion if known."""
    cfg = run.config
    motion = test_motion(run) if motion is None else motion
    scene_rng = named_stream(run.seed, "scene")
    spec = scene_spec(cfg, scene_rng)
    obs, truth = simulate(motion, spec, scene_rng, nominal_body())
    subject = nominal_body() if np.all(truth.segment_scale == 1.0) else nominal_body().scaled(truth.segment_scale)
    observed = Motion(truth.qpos, motion.fps, motion.label, motion.subject, motion.demo, motion.source)
    return observed, obs, truth, subject


def run_inputs(run: RunSpec) -> RunInputs:
    """Everything the methods of one run use (also what ``harness run-video`` re-creates)."""
    cfg = run.config
    if run.code and run.code != code_version():
        raise RunError(f"run {run.key}: this process runs code {code_version()}, the run was planned with "
                       f"{run.code} (every worker must run the same checkout)")
    stream = test_stream(run)
    motion = test_motion(run) if stream is None else stream.motion
    db, db_path = database(cfg, motion, run.cache_dir)
    labels = None if stream is None else stream.labels
    missing = sorted(set(labels) - set(db.classes_) - {TRANSITION}) if stream is not None else (
        [] if run.test_class in db.classes_ else [run.test_class])
    if missing:
        raise RunError(f"run {run.key}: class {missing[0]!r} has no training demonstration in this split")
    observed, obs, truth, subject = simulate_run(run, motion)
    tc = tracker_config(cfg)
    return RunInputs(key=run.key, label=run.test_class, classes=tuple(db.classes_), body=nominal_body(),
                     subject=subject, db=db, motion=observed, obs=obs, truth=truth,
                     tracker=lambda: fresh_tracker(db_path, tc, named_stream(run.seed, "engine")),
                     labels=labels, engine=tc)


def run_one(run: RunSpec) -> list[dict]:
    inputs = run_inputs(run)
    obs, truth = inputs.obs, inputs.truth
    common = {"class_true": run.test_class, "n_frames": len(obs), "mean_flows": float(obs.counts[1:].mean()),
              "self_occlusion": float(truth.self_fraction.mean()),
              "obstacle_occlusion": float(truth.obstacle_fraction.mean())}
    # Where the camera stood: the spec simulate_run drew (first, from the run's "scene" stream).
    common |= viewing_columns(scene_spec(run.config, named_stream(run.seed, "scene")), truth)
    if inputs.labels is not None:
        common["segments_true"] = segment_list(inputs.labels)
    rows = []
    for name in run.config.methods:
        t0 = time.perf_counter()
        scores = METHODS[name].score(inputs)
        ms = 1e3 * (time.perf_counter() - t0) / max(len(obs), 1)
        rows.append({"method": name} | common | scores | {"ms_per_frame": ms})
    return rows


__all__ = ["clear_caches", "database", "fresh_tracker", "nominal_body", "run_inputs", "run_one",
           "simulate_run", "test_motion", "test_stream", "training_motions"]
