"""A scenario's runs as a dataset (``harness export SCENARIO --out DIR``), and its loader (format ``EXPORT_FORMAT``,
``docs/export.md``).

Every run of the scenario's plan is played as ``evaluate`` plays it (``pipeline.play``: the same seeds, scene
and observation) and written as files under ``DIR/runs/<run key>/``: what the camera saw (``observation.npz``,
the engine's observation format), the ground truth (``truth.npz``: base pose, configurations, the surface points
behind the markers, visibility, ...), the test motion as the nominal body performed it (``performed.npz``) and
the metadata (``meta.json``: scene spec as drawn, seeds, split, classes, a stream's labels). ``DIR/index.csv``
has one row per run. No database is trained: a method that learns needs the runs, not the engine.

The export runs through the evaluation's runner: resumable (``DIR/runs.jsonl`` is its journal; a killed export
goes on where it stopped), bounded by the same limits, stale when the scenario or the code changed (``--fresh``),
``--jobs`` and ``--limit`` as for ``evaluate``.

``load_index(DIR)`` reads the index and ``load_run(DIR, key)`` one run as an ``ExportedRun``, whose fields are
those of ``methods.RunInputs`` that files can hold (a test checks that they equal what the pipeline hands a
method).
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Iterator
from dataclasses import dataclass
from functools import partial
from pathlib import Path

import numpy as np
import pandas as pd

from harness.errors import HarnessError
from harness.evaluation.journal import RUN_KEY
from harness.evaluation.runner import RunSpec, run_scenario
from harness.evaluation.scenario import Scenario
from harness.evaluation.viewing import viewing_columns
from harness.io import read_input_bytes, write_text_atomic
from harness.motion import Motion
from harness.observation import Observation
from harness.scene.simulate import GroundTruth
from harness.scene.spec import (CameraSpec, MarkerSpec, ObservationSpec, OccluderGeom, OccluderSpec, SceneSpec,
                                SubjectSpec)
from harness.version import code_version

EXPORT_FORMAT = 1
INDEX_NAME = "index.csv"
ABOUT_NAME = "export.json"
RUNS_DIR = "runs"
MAX_META_BYTES = 16 * 2**20     # a run's meta.json (a stream of 20,000 frames' labels is about 0.3 MB)
MAX_INDEX_BYTES = 1 * 2**30     # 100,000 runs (the plan's limit) of about 400 bytes each, with room


class ExportError(HarnessError):
    """An export directory or run that cannot be read; names the file."""


@dataclass(frozen=True)
class ExportedRun:
    """One exported run, as ``methods.RunInputs`` holds it (less the database, body and engine, which are not
    files of the run).

    key: the run key. label: the true class (``"stream"`` for a stream). classes: the database's classes (sorted;
    what a method's posterior columns are). obs: the observation (what the camera saw). truth: the scene's ground
    truth. motion: the test motion as the observed subject performed it (``truth.qpos``). performed: as the
    nominal body performed it. labels: a stream's true label per frame ``(T,)``, else None. scene: the scene spec
    the run drew. meta: everything of ``meta.json`` (seeds, split, condition).
    """

    key: str
    label: str
    classes: tuple[str, ...]
    obs: Observation
    truth: GroundTruth
    motion: Motion
    performed: Motion
    labels: np.ndarray | None
    scene: SceneSpec
    meta: dict


# --- writing ---------------------------------------------------------------------------------------------

def export_run(out_dir: str | Path, run: RunSpec) -> list[dict]:
    """Write one run's files under ``out_dir/runs/<run key>/`` (each atomically) and return its index row (the
    runner's run function: ``functools.partial(export_run, out_dir)``)."""
    from harness.evaluation.pipeline import check_classes, play, test_motion, test_stream, training_motions

    cfg = run.config
    stream = test_stream(run)
    performed = test_motion(run) if stream is None else stream.motion
    training = training_motions(cfg, performed)
    classes = tuple(sorted({m.label for m in training}))      # what the run's database would hold, in its order
    labels = None if stream is None else stream.labels
    check_classes(run, classes, labels, run.config.classes)
    spec, obs, truth, _, observed = play(run, performed)
    directory = Path(out_dir) / RUNS_DIR / run.key
    obs.save(directory / "observation.npz")
    truth.save(directory / "truth.npz")
    performed.save(directory / "performed.npz")
    split = {"motions": cfg.test.motions, "split": cfg.test.split, "database": cfg.database.source,
             "subject": performed.subject, "demo": performed.demo, "source": performed.source,
             "style": performed.style,
             "training_subjects": sorted({str(m.subject) for m in training})}
    meta = {"format": EXPORT_FORMAT, "key": run.key, "label": run.test_class, "classes": list(classes),
            "seed": run.seed, "scenario_seed": cfg.seed, "scenario": cfg.name, "condition": run.condition_label,
            "swept": {k: v for k, v in run.swept}, "repeat": run.repeat, "source": run.test_source, "test_class": run.test_class,
            "test_demo": run.test_demo, "fps": float(obs.fps), "n_frames": len(obs),
            "motion": {"label": performed.label, "subject": performed.subject, "demo": performed.demo,
                       "source": performed.source, "style": performed.style},
            "split": split, "labels": None if labels is None else [str(v) for v in labels],
            "scene": dataclasses.asdict(spec)}
    write_text_atomic(directory / "meta.json", json.dumps(meta, indent=1, sort_keys=True) + "\n")
    # The runner's rows are one per method; an export's is one per run ("method" is dropped from the index).
    return [{"method": "", "path": f"{RUNS_DIR}/{run.key}", "label": run.test_class, "split": cfg.test.split,
             "subject": str(performed.subject), "demo": str(performed.demo), "style": performed.style,
             "n_frames": len(obs), "fps": float(obs.fps), "mean_flows": float(obs.counts[1:].mean()),
             "markers": int(spec.markers.count)} | viewing_columns(spec, truth)]


def export(scenario: Scenario, out_dir: str | Path, cache_dir: str | Path, jobs: int = 1, limit: int | None = None,
           fresh: bool = False, progress: bool = True) -> pd.DataFrame:
    """Export every run of ``scenario`` not yet in ``out_dir`` (resuming) and write ``index.csv`` and
    ``export.json``; return the index. ``cache_dir``: the runner's cache (the procedural training sets are made,
    no database is trained)."""
    out_dir = Path(out_dir)
    table = run_scenario(scenario, out_dir, partial(export_run, out_dir), jobs=jobs, limit=limit,
                         cache_dir=cache_dir, fresh=fresh, progress=progress)
    index = table.drop(columns=["method"]) if "method" in table else table
    write_text_atomic(out_dir / INDEX_NAME, index.to_csv(index=False))
    (out_dir / "runs.csv").unlink(missing_ok=True)       # the runner's table: the index is it, less ``method``
    about = {"format": EXPORT_FORMAT, "scenario": scenario.name, "code": code_version(), "runs": len(index),
             "index": INDEX_NAME, "loader": "harness.evaluation.export.load_run"}
    write_text_atomic(out_dir / ABOUT_NAME, json.dumps(about, indent=1, sort_keys=True) + "\n")
    return index


# --- reading ---------------------------------------------------------------------------------------------

def load_index(directory: str | Path) -> pd.DataFrame:
    """The export's index: one row per run (``run_key``, ``path`` and the columns of ``docs/export.md``)."""
    directory = Path(directory)
    _check_format(directory)
    data = read_input_bytes(directory / INDEX_NAME, ExportError, "export index", MAX_INDEX_BYTES)
    import io

    return pd.read_csv(io.BytesIO(data), keep_default_na=False, na_values=[""])


def load_run(directory: str | Path, key: str) -> ExportedRun:
    """One exported run (``key``: its run key, e.g. ``c000/r000/walk/d008``)."""
    directory = Path(directory)
    if not isinstance(key, str) or not RUN_KEY.match(key):
        raise ExportError(f"{key!r}: not a run key (like c000/r000/walk/d008)")
    run_dir = directory / RUNS_DIR / key
    meta = _json(run_dir / "meta.json", "run metadata", MAX_META_BYTES)
    if meta.get("format") != EXPORT_FORMAT:
        raise ExportError(f"{run_dir / 'meta.json'}: export format {meta.get('format')!r}, this loader reads "
                          f"{EXPORT_FORMAT}")
    try:
        obs = Observation.load(run_dir / "observation.npz")
        truth = GroundTruth.load(run_dir / "truth.npz")
        performed = Motion.load(run_dir / "performed.npz")
    except HarnessError as exc:
        raise ExportError(str(exc)) from None
    ident = meta["motion"]
    performed = Motion(performed.qpos, performed.fps, ident["label"], ident["subject"], ident["demo"],
                       ident["source"])
    observed = Motion(truth.qpos, performed.fps, ident["label"], ident["subject"], ident["demo"], ident["source"])
    labels = None if meta["labels"] is None else np.asarray(meta["labels"])
    return ExportedRun(key=meta["key"], label=meta["label"], classes=tuple(meta["classes"]), obs=obs, truth=truth,
                       motion=observed, performed=performed, labels=labels, scene=scene_from_dict(meta["scene"]),
                       meta=meta)


def load_runs(directory: str | Path) -> Iterator[ExportedRun]:
    """Every exported run, in the index's order (run key order), one at a time."""
    for key in load_index(directory)["run_key"]:
        yield load_run(directory, key)


def scene_from_dict(d: dict) -> SceneSpec:
    """The ``SceneSpec`` of ``dataclasses.asdict(spec)`` (as ``meta.json`` holds it)."""
    occ = dict(d["occluders"])
    occ["geoms"] = tuple(OccluderGeom(g["type"], tuple(g["pos"]), tuple(g["size"]), g["yaw"]) for g in occ["geoms"])
    return SceneSpec(MarkerSpec(**d["markers"]), CameraSpec(**d["camera"]), OccluderSpec(**occ),
                     ObservationSpec(**d["observation"]), SubjectSpec(**d["subject"]))


def _check_format(directory: Path) -> None:
    about = _json(directory / ABOUT_NAME, "export description", 2**20)
    if about.get("format") != EXPORT_FORMAT:
        raise ExportError(f"{directory / ABOUT_NAME}: export format {about.get('format')!r}, this loader reads "
                          f"{EXPORT_FORMAT}")


def _json(path: Path, kind: str, max_bytes: int) -> dict:
    data = read_input_bytes(path, ExportError, kind, max_bytes)
    try:
        value = json.loads(data)
    except (ValueError, RecursionError):
        raise ExportError(f"{path}: not {kind} (not JSON)") from None
    if not isinstance(value, dict):
        raise ExportError(f"{path}: not {kind} (not a JSON object)")
    return value
