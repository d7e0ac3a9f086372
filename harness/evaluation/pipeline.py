"""One evaluation run: train (or load) the database, play the test motion in the scene, run every method of
the scenario (``harness.evaluation.methods``), score it against the ground truth.
``run_one(RunSpec) -> list[dict]``, one row per method.

Random generators per run (all from the run's seed): the test motion, the scene (markers, azimuth, subject,
noise), and the engine's particle filter, so that adding a method never changes another method's numbers.

The database is keyed by its training set: ``training_motions`` is the one rule of what trains a run's
database (its exclusions keep the test motion out), and the cache key is computed from the identities of the
motions it returns (``training_identity``: source, class, subject, demo, frames, frame rate and a hash of the
configurations), so that no exclusion rule can change without the key changing.

Nothing is kept between runs but caches by value, whose entries are never changed: the body model, capture
sets (by directory, manifest and frame rate), procedural training sets, databases (by their cache key) and
engine prototypes (by database and ``TrackerConfig``). Each run gets its own engine: a shallow copy of the
prototype with the run's random generator (``Tracker.reset`` builds all per-sequence state anew on the copy),
so runs in one process give the rows they give alone, in any order (tested).
"""

from __future__ import annotations

import copy
import hashlib
import time
from functools import lru_cache
from pathlib import Path

import numpy as np

from harness.body import nominal_body
from harness.engine import MotionDatabase, Tracker, TrackerConfig
from harness.evaluation.cache import cached, path_for_key
from harness.evaluation.external import resolve
from harness.evaluation.methods import EngineRuns, Method, MethodError, RunInputs, run_method, segment_list
from harness.evaluation.runner import PROCEDURAL, RunError, RunSpec
from harness.evaluation.scenario import Scenario, scene_spec, tracker_config
from harness.evaluation.viewing import viewing_columns
from harness.motion import Motion
from harness.motion.performer import CYCLIC, demonstrations, training_set
from harness.motion.stream import TRANSITION, Stream, capture_stream, procedural_stream
from harness.randomness import named_generator
from harness.scene.simulate import simulate
from harness.version import code_version

TEST_SUBJECT_OFFSET = 1000                         # held-out procedural demos use subjects never used in training
DATABASE_FORMAT = 2


# --- motions --------------------------------------------------------------------------------------------

@lru_cache(maxsize=8)
def _capture_motions(capture_dir: str, manifest: str, fps: float) -> tuple[Motion, ...]:
    """One motion per manifest row of a capture set, in manifest order (``npz`` rows loaded, others retargeted)."""
    from harness.motion.captures import read_manifest, row_motions

    rows = read_manifest(Path(capture_dir) / manifest, name=Path(capture_dir).name)
    return tuple(row_motions(capture_dir, rows, fps, nominal_body()))


def _captures(cfg: Scenario) -> tuple[Motion, ...]:
    """Every capture motion of the scenario, set by set (the order of ``capture_splits.capture_rows``)."""
    return tuple(m for d in cfg.database.capture_dirs or ()
                 for m in _capture_motions(d, cfg.database.manifest, float(cfg.database.fps)))


def test_window(motion: Motion, window_s: float | None) -> Motion:
    """A capture test motion cut to its middle ``window_s`` seconds (``test.window_s``; None or a shorter motion:
    itself)."""
    if window_s is None or motion.duration <= window_s:
        return motion
    n = int(round(window_s * motion.fps)) + 1
    start = (motion.n_frames - n) // 2
    return motion.slice(start, start + n)


@lru_cache(maxsize=4)
def _procedural_training(classes: tuple[str, ...], demos: int, seed: int, fps: float) -> tuple[Motion, ...]:
    return tuple(training_set(classes, demos, seed, fps, body=nominal_body()))


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
        return _capture_stream(cfg.database.capture_dirs[0], cfg.database.manifest, stream.takes[run.test_demo],
                               float(cfg.database.fps))
    return procedural_stream(named_generator(run.seed, "motion"), classes=cfg.classes, primitives=stream.primitives,
                             transition_s=stream.transition_s, fps=cfg.database.fps,
                             subject=TEST_SUBJECT_OFFSET + run.test_demo, body=nominal_body(),
                             demo=str(run.test_demo), left=cfg.test.left)


def test_motion(run: RunSpec) -> Motion:
    """The run's test motion as the nominal body performs it (the scene plays it on the scenario's subject)."""
    cfg = run.config
    if cfg.test.stream is not None:
        return test_stream(run).motion
    if run.test_source != PROCEDURAL:
        from harness.evaluation.capture_splits import capture_rows, row_index

        demos = row_index(capture_rows(cfg)).get((run.test_source, run.test_class), [])
        if run.test_demo >= len(demos):
            raise RunError(f"run {run.key}: set {run.test_source!r} has {len(demos)} rows of {run.test_class!r}")
        return test_window(_captures(cfg)[demos[run.test_demo]], cfg.test.window_s)
    return demonstrations(run.test_class, 1, named_generator(run.seed, "motion"), fps=cfg.database.fps,
                          subject=TEST_SUBJECT_OFFSET + run.test_demo, body=nominal_body(), left=cfg.test.left)[0]


def training_motions(cfg: Scenario, test: Motion | None) -> list[Motion]:
    """What trains the database of a run testing ``test`` (None: the scenario's whole training set); the one
    place of the exclusion rules, with ``capture_splits``.

    Procedural demonstrations (``database.source`` procedural or both): ``performer.training_set``, subjects
    never used for tests. Capture rows (captures or both): every row of the database's classes (never
    ``other``) of at least ``database.states`` frames that ``database.select`` lets it learn, but those of a
    capture test motion's group under
    ``test.split`` (``capture_splits.holds_out``);
    for a capture stream, every row of its take. Only the scenario's classes are learned."""
    from harness.evaluation.capture_splits import holds_out, selected_motion

    db = cfg.database
    out = []
    if db.learns_procedural:
        out += list(_procedural_training(tuple(cfg.classes), db.train_demos, db.seed, float(db.fps)))
    if db.learns_captures:
        # A left-to-right chain needs a frame per state: shorter rows (two Bandai dashes of 0.6 s) only test.
        motions = [m for m in _captures(cfg) if m.label in cfg.classes and m.n_frames >= db.states
                   and selected_motion(m, db.select)]
        if test is not None and cfg.test.stream is not None:
            # A capture stream is a whole take: none of its rows trains the database.
            take = test.demo.split(":")[0]
            motions = [m for m in motions if m.demo.split(":")[0] != take]
        elif test is not None and test.source != PROCEDURAL:
            motions = [m for m in motions if not holds_out(test, m, cfg.test.split)]
        out += motions
    return out


def training_identity(motion: Motion) -> dict:
    """What tells one training motion from any other: its source (procedural or the capture set), class,
    subject, style, demo (a capture's file and frame range), length, frame rate and a hash of its configurations
    (which also changes when the file behind a capture, its retargeting or the performer changes)."""
    digest = hashlib.sha256(np.ascontiguousarray(motion.qpos, dtype=float).tobytes()).hexdigest()[:16]
    return {"source": motion.source, "label": motion.label, "subject": str(motion.subject), "style": motion.style,
            "demo": str(motion.demo), "frames": int(motion.n_frames), "fps": float(motion.fps), "qpos_sha256": digest}


def database_key(cfg: Scenario, training: list[Motion]) -> dict:
    """What a database depends on (its cache key): the identities of its training motions, the HMM settings
    (states, cyclic classes, both-handed or not) and the code version."""
    db = cfg.database
    return {"states": db.states, "cyclic": list(CYCLIC), "mirrored": db.mirrored, "background": db.background,
            "by_source": db.by_source,
            "format": DATABASE_FORMAT, "code": code_version(), "training": [training_identity(m) for m in training]}


@lru_cache(maxsize=8)
def _stored_database(path: str) -> MotionDatabase:
    return MotionDatabase.load(path)


def database(cfg: Scenario, test: Motion | None, cache_dir: str | Path) -> tuple[MotionDatabase, str]:
    """The run's database (trained once per distinct training set, cached on disk) and its cache path."""
    training = training_motions(cfg, test)
    path = path_for_key(Path(cache_dir) / "databases", database_key(cfg, training))

    def build():
        return MotionDatabase(n_states=cfg.database.states, cyclic=CYCLIC, mirrored=cfg.database.mirrored,
                              background=cfg.database.background, by_source=cfg.database.by_source).fit(training)

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
    for f in (nominal_body, _capture_motions, _procedural_training, _capture_stream, _stored_database, _prototype):
        f.cache_clear()


# --- one run --------------------------------------------------------------------------------------------

def check_classes(run: RunSpec, classes, labels: np.ndarray | None, scenario_classes) -> None:
    """``RunError`` when the run's class (or a stream's label) is one of the scenario's but has no training
    demonstration in the split (a class the scenario does not have is an open-set test motion)."""
    missing = sorted(set(labels) - set(classes) - {TRANSITION}) if labels is not None else (
        [] if run.test_class in classes or run.test_class not in scenario_classes else [run.test_class])
    if missing:
        raise RunError(f"run {run.key}: class {missing[0]!r} has no training demonstration in this split")


def play(run: RunSpec, motion: Motion):
    """The test motion played in the run's scene (the scene spec drawn from the run's scene generator, once):
    ``(spec, observation, ground truth, the observed subject's body, the motion as that subject performed it)``."""
    scene_rng = named_generator(run.seed, "scene")
    spec = scene_spec(run.config, scene_rng)
    obs, truth = simulate(motion, spec, scene_rng, nominal_body())
    subject = nominal_body() if np.all(truth.segment_scale == 1.0) else nominal_body().scaled(truth.segment_scale)
    return spec, obs, truth, subject, motion.replace(qpos=truth.qpos)


def run_inputs(run: RunSpec) -> RunInputs:
    """Everything the methods of one run use (also what ``harness run-video`` re-creates): the test motion
    played in the run's scene (the scene spec drawn from the run's scene generator, once), the database, the
    ground truth and the engine factory."""
    cfg = run.config
    if run.code and run.code != code_version():
        raise RunError(f"run {run.key}: this process runs code {code_version()}, the run was planned with "
                       f"{run.code} (every worker must run the same checkout)")
    stream = test_stream(run)
    motion = test_motion(run) if stream is None else stream.motion
    db, db_path = database(cfg, motion, run.cache_dir)
    labels = None if stream is None else stream.labels
    check_classes(run, db.classes_, labels, cfg.classes)
    spec, obs, truth, subject, observed = play(run, motion)
    tc = tracker_config(cfg)
    return RunInputs(key=run.key, label=run.test_class, classes=tuple(db.classes_), body=nominal_body(),
                     subject=subject, db=db, motion=observed, obs=obs, truth=truth,
                     tracker=lambda: fresh_tracker(db_path, tc, named_generator(run.seed, "engine")),
                     labels=labels, engine=tc, scene=spec, performed=motion)


def run_one(run: RunSpec) -> list[dict]:
    inputs = run_inputs(run)
    obs, truth = inputs.obs, inputs.truth
    common = {"class_true": run.test_class, "style": inputs.motion.style, "open_set": inputs.open_set,
              "n_frames": len(obs), "mean_flows": float(obs.counts[1:].mean()),
              "self_occlusion": float(truth.self_fraction.mean()),
              "obstacle_occlusion": float(truth.obstacle_fraction.mean())}
    common |= viewing_columns(inputs.scene, truth)         # where the camera stood: the spec the run drew
    if inputs.labels is not None:
        common["segments_true"] = segment_list(inputs.labels)
    engine = EngineRuns(inputs)
    rows = []
    for name in run.config.methods:
        t0 = time.perf_counter()
        m = _method(run, name)
        scores = run_method(m, inputs, engine)
        ms = 1e3 * (time.perf_counter() - t0) / max(len(obs), 1)
        rows.append({"method": name} | common | scores | {"ms_per_frame": ms})
    return rows


def _method(run: RunSpec, name: str) -> Method:
    """The run's method ``name``; a method from outside the package must be the code the run was planned with
    (its version stamped on the scenario at load), as the harness's own code must (``run_inputs``)."""
    try:
        m = resolve(name)
    except MethodError as exc:
        raise RunError(f"run {run.key}: {exc}") from None
    planned = run.config.method_versions.get(name, "")
    if m.version != planned:
        raise RunError(f"run {run.key}: method {name!r} is version {m.version or 'built in'} in this process, the "
                       f"run was planned with {planned or 'a built-in method'} (its code changed: evaluate again "
                       f"with --fresh)")
    return m


__all__ = ["check_classes", "clear_caches", "database", "database_key", "fresh_tracker", "play", "run_inputs",
           "run_one", "test_motion", "test_stream", "training_identity", "training_motions"]
