"""A corpus of malformed inputs, each through the real command line: exit 2, exactly one line on stderr that names
the file, no traceback, and nothing written."""

import os
import zipfile
from pathlib import Path

import numpy as np
import pytest

from harness.cli import main
from harness.engine import MotionDatabase
from harness.observation import Observation
from harness.pinhole import Intrinsics

# --- scenarios: `harness evaluate FILE` -----------------------------------------------------------------

SCENARIOS = {
    "binary": b"\x89PNG\r\n\x1a\n" + bytes(range(256)),
    "nul_bytes": b"name: x\x00\n",
    "not_yaml": "name: x\ncamera: {distance: 3\n",
    "a_list": "- name\n- x\n",
    "a_scalar": "hello\n",
    "no_name": "seed: 3\n",
    "bad_name": "name: ../escape\n",
    "unknown_key": "name: x\ncamera:\n  distnce: 4\n",
    "preset_moat": "name: x\noccluders: {preset: moat, amount: 0.2}\n",
    "amount_one": "name: x\noccluders: {preset: low_wall, amount: 1.0}\n",
    "amount_without_preset": "name: x\noccluders: {amount: 0.3}\n",
    "distance_inf": "name: x\ncamera: {distance: .inf}\n",
    "distance_zero": "name: x\ncamera: {distance: 0}\n",
    "azimuth_nan": "name: x\ncamera: {azimuth: .nan}\n",
    "azimuth_word": "name: x\ncamera: {azimuth: left}\n",
    "camera_in_body": "name: x\ncamera: {distance: 0.05, elevation: 0}\n",
    "camera_in_body_random": "name: x\ncamera: {distance: 0.1, azimuth: random}\n",
    "camera_below_floor": "name: x\ncamera: {distance: 4, elevation: -60}\n",
    "camera_in_obstacle": "name: x\ncamera: {distance: 4, elevation: 0}\n"
                          "occluders:\n  geoms: [{type: box, pos: [4, 0, 1], size: [0.5, 0.5, 1]}]\n",
    "elevation_90": "name: x\ncamera: {elevation: 90}\n",
    "fovy_zero": "name: x\ncamera: {fovy: 0}\n",
    "width_small": "name: x\ncamera: {width: 8}\n",
    "motion_fly": "name: x\ncamera: {motion: fly}\n",
    "look_at_inf": "name: x\ncamera: {look_at_height: .inf}\n",
    "markers_zero": "name: x\nmarkers: {count: 0}\n",
    "markers_fraction": "name: x\nmarkers: {count: 2.5}\n",
    "dropout_one": "name: x\nobservation: {dropout: 1.0}\n",
    "outliers_negative": "name: x\nobservation: {outliers: -1}\n",
    "noise_nan": "name: x\nobservation: {noise_px: .nan}\n",
    "mode_film": "name: x\nobservation: {mode: film}\n",
    "particles_zero": "name: x\nengine: {tracks: {particles: 0}}\n",
    "init_distance_reversed": "name: x\nengine: {spawn: {distance: [5, 2]}}\n",
    "engine_noise_negative": "name: x\nengine: {likelihood: {noise_px: -1}}\n",
    "engine_outlier_prob": "name: x\nengine: {likelihood: {outlier_prob: 1.5}}\n",
    "engine_unknown": "name: x\nengine: {bogus: 1}\n",
    "engine_flat_key": "name: x\nengine: {particles: 100}\n",
    "method_unknown": "name: x\nmethods: [full, best]\n",
    "methods_empty": "name: x\nmethods: []\n",
    "repeats_huge": "name: x\nrepeats: 1000000000000\n",
    "plan_huge": "name: x\nrepeats: 5000\nsweep: {markers.count: [10, 20, 30]}\n",
    "sweep_not_mapping": "name: x\nsweep: [markers.count]\n",
    "sweep_not_list": "name: x\nsweep: {markers.count: 10}\n",
    "sweep_unknown": "name: x\nsweep: {markers.cont: [10]}\n",
    "sweep_empty": "name: x\nsweep: {markers.count: []}\n",
    "sweep_bad_value": "name: x\nsweep: {camera.distance: [4, .inf]}\n",
    "scale_three": "name: x\nsubject: {scale: 3}\n",
    "limb_scale_half": "name: x\nsubject: {limb_scale: 0.5}\n",
    "geom_type": "name: x\noccluders:\n  geoms: [{type: cone, pos: [1, 0, 0.5], size: [0.2, 0.5]}]\n",
    "geom_box_two_sizes": "name: x\noccluders:\n  geoms: [{type: box, pos: [1, 0, 0.5], size: [0.2, 0.5]}]\n",
    "geom_negative_size": "name: x\noccluders:\n  geoms: [{type: cylinder, pos: [1, 0, 0.5], size: [-0.2, 0.5]}]\n",
    "geom_with_preset": "name: x\noccluders:\n  preset: low_wall\n  geoms: [{type: box, pos: [2, 0, 0.5], size: [0.1, 1, 0.5]}]\n",
    "class_typo": "name: x\ndatabase: {classes: [walk, wlak]}\n",
    "split_mismatch": "name: x\ntest: {split: all}\n",
    "fps_zero": "name: x\ndatabase: {fps: 0}\n",
    "seed_negative": "name: x\nseed: -1\n",
}


@pytest.mark.parametrize("case", sorted(SCENARIOS))
def test_bad_scenario(case, tmp_path, capsys):
    path = tmp_path / f"{case}.yaml"
    content = SCENARIOS[case]
    path.write_bytes(content if isinstance(content, bytes) else content.encode())
    _check(["evaluate", str(path), "--results", str(tmp_path / "results")], path, tmp_path, capsys)


def test_missing_and_directory_scenarios(tmp_path, capsys):
    _check(["evaluate", str(tmp_path / "none.yaml"), "--results", str(tmp_path / "r")], tmp_path / "none.yaml",
           tmp_path, capsys)
    (tmp_path / "dir.yaml").mkdir()
    _check(["evaluate", str(tmp_path / "dir.yaml"), "--results", str(tmp_path / "r")], tmp_path / "dir.yaml",
           tmp_path, capsys)


# --- observation files and databases: `harness track OBS --database DB --out EST` --------------------------

def _observation() -> Observation:
    rng = np.random.default_rng(0)
    flows = [np.empty((0, 4))] + [np.column_stack([rng.uniform(0, 600, 20), rng.uniform(0, 400, 20),
                                                   rng.normal(0, 30, (20, 2))]) for _ in range(4)]
    return Observation(30.0, Intrinsics.from_fov(45.0, 640, 480), flows)


def _arrays(obs: Observation) -> dict:
    with np.load(_save(obs)) as z:
        return {k: z[k] for k in z.files}


_TMP = Path(os.environ.get("TMPDIR", "/tmp"))


def _save(obs: Observation) -> Path:
    import tempfile

    path = Path(tempfile.mkdtemp()) / "ok.npz"
    obs.save(path)
    return path


def _npz(path: Path, arrays: dict) -> None:
    with open(path, "wb") as fh:
        np.savez(fh, **arrays)


def _obs_case(name: str, path: Path) -> None:
    good = _arrays(_observation())
    if name == "empty":
        path.write_bytes(b"")
    elif name == "truncated":
        _npz(path, good)
        path.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    elif name == "random_bytes":
        path.write_bytes(np.random.default_rng(1).bytes(500))
    elif name == "text":
        path.write_text("root:x:0:0:root:/root:/bin/bash\n")
    elif name == "npy_not_npz":
        np.save(path.with_suffix(".npy"), np.zeros(3))
        path.write_bytes(path.with_suffix(".npy").read_bytes())
        path.with_suffix(".npy").unlink()
    elif name == "zip_of_text":
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("notes.txt", "hello")
    elif name == "no_flows":
        _npz(path, {k: v for k, v in good.items() if k != "flows"})
    elif name == "flows_3_columns":
        _npz(path, good | {"flows": good["flows"][:, :3]})
    elif name == "frame_decreasing":
        _npz(path, good | {"frame": good["frame"][::-1].copy()})
    elif name == "nan_flow":
        f = good["flows"].copy()
        f[3, 2] = np.nan
        _npz(path, good | {"flows": f})
    elif name == "negative_frames":
        _npz(path, good | {"n_frames": np.array(-4)})
    elif name == "intrinsics_5":
        _npz(path, good | {"intrinsics": good["intrinsics"][:5]})
    elif name == "fps_zero":
        _npz(path, good | {"fps": np.array(0.0)})
    elif name == "outside_image":
        f = good["flows"].copy()
        f[0, 0] = 5000.0
        _npz(path, good | {"flows": f})
    elif name == "pickled_object":
        _npz(path, good | {"fps": np.array([{"a": 1}], dtype=object)})
    else:
        raise AssertionError(name)


OBSERVATION_CASES = ("empty", "truncated", "random_bytes", "text", "npy_not_npz", "zip_of_text", "no_flows",
                     "flows_3_columns", "frame_decreasing", "nan_flow", "negative_frames", "intrinsics_5",
                     "fps_zero", "outside_image", "pickled_object")


@pytest.fixture(scope="module")
def database_file(tmp_path_factory, body):
    from harness.motion.performer import CYCLIC
    from harness.motion.performer import training_set

    path = tmp_path_factory.mktemp("db") / "db.npz"
    MotionDatabase(n_states=3, cyclic=CYCLIC).fit(training_set(["walk", "squat"], 2, 0, body=body)).save(path)
    return path


@pytest.mark.parametrize("case", OBSERVATION_CASES)
def test_bad_observation(case, tmp_path, capsys, database_file):
    path = tmp_path / f"{case}.npz"
    _obs_case(case, path)
    _check(["track", str(path), "--database", str(database_file), "--out", str(tmp_path / "est.npz")], path,
           tmp_path, capsys)


def _db_case(name: str, path: Path, good: Path) -> None:
    with np.load(good) as z:
        arrays = {k: z[k] for k in z.files}
    if name == "empty":
        path.write_bytes(b"")
    elif name == "truncated":
        path.write_bytes(good.read_bytes()[:300])
    elif name == "random_bytes":
        path.write_bytes(np.random.default_rng(2).bytes(800))
    elif name == "no_format":
        _npz(path, {k: v for k, v in arrays.items() if k != "format"})
    elif name == "wrong_format":
        _npz(path, arrays | {"format": np.array("something else")})
    elif name == "nan_means":
        m = arrays["means"].copy()
        m[0, 0, 0] = np.nan
        _npz(path, arrays | {"means": m})
    elif name == "shape_mismatch":
        _npz(path, arrays | {"covars": arrays["covars"][:, :2]})
    elif name == "observation_file":
        _observation().save(path)
    else:
        raise AssertionError(name)


DATABASE_CASES = ("empty", "truncated", "random_bytes", "no_format", "wrong_format", "nan_means", "shape_mismatch",
                  "observation_file")


@pytest.mark.parametrize("case", DATABASE_CASES)
def test_bad_database(case, tmp_path, capsys, database_file):
    obs = tmp_path / "obs.npz"
    _observation().save(obs)
    path = tmp_path / f"{case}_db.npz"
    _db_case(case, path, database_file)
    _check(["track", str(obs), "--database", str(path), "--out", str(tmp_path / "est.npz")], path, tmp_path, capsys)


# --- captures: `harness capture-video FILE` and `harness import-capture DIR` ----------------------------------

BVH_OK_HEAD = "HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n  CHANNELS 6 Xposition Yposition Zposition Zrotation " \
              "Yrotation Xrotation\n  End Site\n  {\n    OFFSET 0 1 0\n  }\n}\n"
CAPTURE_FILES = {
    "empty.bvh": b"",
    "binary.bvh": bytes(range(256)) * 4,
    "passwd.bvh": b"root:x:0:0:root:/root:/bin/bash\n",
    "no_motion.bvh": BVH_OK_HEAD.encode(),
    "short_frames.bvh": (BVH_OK_HEAD + "MOTION\nFrames: 3\nFrame Time: 0.01\n0 0 0 0 0 0\n").encode(),
    "bad_number.bvh": (BVH_OK_HEAD + "MOTION\nFrames: 1\nFrame Time: 0.01\n0 0 x 0 0 0\n").encode(),
    "unbalanced.bvh": b"HIERARCHY\nROOT Hips\n{\n  OFFSET 0 0 0\n",
    "garbage.amc": bytes(range(200)),
    "notes.txt": b"hello\n",
}


@pytest.mark.parametrize("name", sorted(CAPTURE_FILES))
def test_bad_capture_file(name, tmp_path, capsys):
    path = tmp_path / name
    path.write_bytes(CAPTURE_FILES[name])
    argv = ["capture-video", str(path), "--out", str(tmp_path / "out.mp4")]
    if name.endswith(".amc"):
        (tmp_path / "empty.asf").write_bytes(b"")
        argv += ["--skeleton", str(tmp_path / "empty.asf")]
    _check(argv, path if not name.endswith(".amc") else tmp_path / "empty.asf", tmp_path, capsys)


HEADER = "file,format,skeleton,subject,trial,class,start,end,fps\n"
MANIFESTS = {
    "header_only": HEADER,
    "empty": "",
    "absolute_path": HEADER + "/etc/passwd,bvh,,1,1,walk,0,10,120\n",
    "parent_path": HEADER + "../../x.bvh,bvh,,1,1,walk,0,10,120\n",
    "parent_skeleton": HEADER + "a.amc,amc,../s.asf,1,1,walk,0,10,120\n",
    "missing_column": "file,format,subject,class\na.bvh,bvh,1,walk\n",
    "bad_format": HEADER + "a.fbx,fbx,,1,1,walk,0,10,120\n",
    "start_word": HEADER + "a.bvh,bvh,,1,1,walk,zero,10,120\n",
    "empty_range": HEADER + "a.bvh,bvh,,1,1,walk,10,10,120\n",
    "fps_negative": HEADER + "a.bvh,bvh,,1,1,walk,0,10,-1\n",
    "fps_nan": HEADER + "a.bvh,bvh,,1,1,walk,0,10,nan\n",
    "amc_without_skeleton": HEADER + "a.amc,amc,,1,1,walk,0,10,120\n",
    "missing_file": HEADER + "nothere.bvh,bvh,,1,1,walk,0,10,120\n",
    "too_few_cells": HEADER + "a.bvh,bvh,,1\n",
    "empty_class": HEADER + "a.bvh,bvh,,1,1,,0,10,120\n",
    "binary": bytes(range(256)).decode("latin-1"),
    "nul": HEADER + "a.bvh,bvh,,1,1,walk,0,10,120\x00\n",
}


@pytest.mark.parametrize("case", sorted(MANIFESTS))
def test_bad_manifest(case, tmp_path, capsys):
    capture = tmp_path / "captures"
    capture.mkdir()
    path = capture / "MANIFEST.csv"
    path.write_bytes(MANIFESTS[case].encode("latin-1"))
    err = _check(["import-capture", str(capture), "--out", str(tmp_path / "motions")], path, tmp_path, capsys)
    assert "root:x" not in err


# --- issue 23: every group of bad input, refused at load ---------------------------------------------------
#
# Each case is a builder ``(tmp_path, ctx) -> (argv, named)``: it writes its inputs under tmp_path and returns
# the command line and the file (or argument) the one-line error must name. ``_check`` then requires exit 2,
# one line, no traceback, and the tree under tmp_path unchanged, names and contents.

TINY_YAML = ("name: tiny\nseed: 5\ndatabase: {classes: [walk, run]}\ntest: {demos_per_class: 1}\n"
             "methods: [full, gt_base]\n")


def _scenario(text: str, name: str = "case.yaml"):
    def build(tmp_path, ctx):
        path = tmp_path / name
        path.write_text(text)
        return ["evaluate", str(path), "--results", str(tmp_path / "results")], path
    return build


def _sweep_values(n: int) -> str:
    return "[" + ", ".join(str(i) for i in range(1, n + 1)) + "]"


_BOMB = ("a: &a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1]\nb: &b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a]\n"
         "c: &c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b]\nd: &d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c]\n"
         "e: &e [*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]\n")

PATH_CASES = {
    "name_dotdot": _scenario("name: ..\n"),
    "name_dot": _scenario("name: .\n"),
    "name_slash": _scenario("name: a/b\n"),
    "name_hidden": _scenario("name: .hidden\n"),
    "name_dash": _scenario("name: -rf\n"),
    "name_cache": _scenario("name: cache\n"),
    "name_baseline": _scenario("name: baseline\n"),
    "manifest_absolute": _scenario("name: x\ndatabase: {source: captures, manifest: /etc/passwd}\n"
                                   "test: {motions: captures, split: none}\n"),
    "manifest_parent": _scenario("name: x\ndatabase: {source: captures, manifest: ../outside/M.csv}\n"
                                 "test: {motions: captures, split: none}\n"),
    "capture_dir_former_key": _scenario("name: x\ndatabase: {source: captures, capture_dir: a}\n"),
    "split_former_value": _scenario("name: x\ntest: {split: cross_subject}\n"),
}

SWEEP_CASES = {
    "sweep_seed": _scenario("name: x\nsweep: {seed: [1, 2]}\n"),
    "sweep_capture_sets": _scenario("name: x\nsweep: {database.capture_sets: [[a], [b]]}\n"),
    "sweep_manifest": _scenario("name: x\nsweep: {database.manifest: [a.csv, b.csv]}\n"),
    "sweep_cross_field": _scenario("name: x\noccluders: {amount: 0.4}\nsweep: {occluders.preset: [pillar, none]}\n"),
    "sweep_cross_field_two_keys": _scenario("name: x\nsweep: {occluders.preset: [none, low_wall], "
                                            "occluders.amount: [0.0, 0.3]}\n"),
    "sweep_split_per_condition": _scenario("name: x\ndatabase: {source: captures}\n"
                                           "sweep: {test.motions: [captures, procedural]}\n"),
    "sweep_1001_values": _scenario("name: x\nsweep: {markers.count: " + _sweep_values(1001) + "}\n"),
    "sweep_too_many_conditions": _scenario("name: x\nsweep: {markers.count: " + _sweep_values(40)
                                           + ", camera.distance: " + _sweep_values(40) + "}\n"),
    "sweep_key_not_text": _scenario("name: x\nsweep: {1: [2, 3]}\n"),
    "sweep_date_value": _scenario("name: x\nsweep: {markers.count: [2020-01-01, 3]}\n"),
    "sweep_not_a_section": _scenario("name: x\ncamera: 5\nsweep: {camera.distance: [3, 4]}\n"),
    "sweep_repeats_plan": _scenario("name: x\nsweep: {repeats: [1, 6000]}\n"),
}

ENGINE_CASES = {
    "particles_1e12": _scenario("name: x\nengine: {tracks: {particles: 1.0e+12}}\n"),
    "model_points_1e9": _scenario("name: x\nengine: {model: {points: 1000000000}}\n"),
    "hypothesis_points": _scenario("name: x\nengine: {tracks: {particles: 50000}}\n"),
    "open_cell_zero": _scenario("name: x\nengine: {likelihood: {open_cell_px: 0}}\n"),
    "weigh_classes_zero": _scenario("name: x\nengine: {tracks: {weigh_classes: 0}}\n"),
    "init_keep_zero": _scenario("name: x\nengine: {spawn: {keep: 0}}\n"),
    "init_keep_five": _scenario("name: x\nengine: {spawn: {keep: 5}}\n"),
    "model_seed_negative": _scenario("name: x\nengine: {model: {seed: -1}}\n"),
    "position_noise_negative": _scenario("name: x\nengine: {motion: {position_noise: -1}}\n"),
    "weight_iterations_negative": _scenario("name: x\nengine: {likelihood: {weight_iterations: -1}}\n"),
    "refine_iterations_negative": _scenario("name: x\nengine: {recovery: {refine_iterations: -2}}\n"),
    "recover_tracks_negative": _scenario("name: x\nengine: {recovery: {tracks: -1}}\n"),
    "smoothing_frames_negative": _scenario("name: x\nengine: {offline: {smoothing_frames: -3}}\n"),
    "weigh_class_mass_two": _scenario("name: x\nengine: {tracks: {weigh_class_mass: 2}}\n"),
    "floor_std_zero": _scenario("name: x\nengine: {likelihood: {floor_std: 0}}\n"),
    "track_turns_many": _scenario("name: x\nengine: {spawn: {turns: " + _sweep_values(17) + "}}\n"),
    "em_iterations_huge": _scenario("name: x\nengine: {recovery: {em_iterations: 100000}}\n"),
}

SIZE_CASES = {
    "markers_1e9": _scenario("name: x\nmarkers: {count: 1000000000}\n"),
    "camera_1e8_px": _scenario("name: x\ncamera: {width: 100000000, height: 100000000}\n"),
    "fovy_175": _scenario("name: x\ncamera: {fovy: 175}\n"),
    "distance_1e6": _scenario("name: x\ncamera: {distance: 1000000}\n"),
    "look_at_1e6": _scenario("name: x\ncamera: {look_at_height: 1000000}\n"),
    "stream_primitives_1e8": _scenario("name: x\ntest: {stream: {primitives: [2, 100000000]}}\n"
                                       "engine: {belief: {primitive_switch: 0.01}}\n"),
    "stream_transition_100s": _scenario("name: x\ntest: {stream: {transition_s: [0.3, 100]}}\n"),
    "run_frames": _scenario("name: x\ndatabase: {fps: 1000}\ntest: {stream: {primitives: [20, 20]}}\n"),
    "run_memory": _scenario("name: x\nengine: {tracks: {particles: 8000}, model: {points: 300}}\n"),
    "run_memory_swept": _scenario("name: x\nsweep: {engine.model.points: [100, 2000], "
                                  "engine.tracks.particles: [100, 1000]}\n"),
    "sweep_20000_values": _scenario("name: x\nsweep: {markers.count: " + _sweep_values(20000) + "}\n"),
}

YAML_CASES = {
    "alias_bomb": _scenario("name: x\n" + _BOMB + "f: [*e, *e, *e, *e, *e, *e, *e, *e, *e, *e]\n"),
    "alias_bomb_in_sweep": _scenario("name: x\nsweep:\n  markers.count: [[&a [1, 1, 1, 1, 1, 1, 1, 1, 1, 1], "
                                     "&b [*a, *a, *a, *a, *a, *a, *a, *a, *a, *a], "
                                     "&c [*b, *b, *b, *b, *b, *b, *b, *b, *b, *b], "
                                     "&d [*c, *c, *c, *c, *c, *c, *c, *c, *c, *c], "
                                     "[*d, *d, *d, *d, *d, *d, *d, *d, *d, *d]]]\n"),
    "recursive_alias": _scenario("name: x\nsweep: {markers.count: &r [*r]}\n"),
    "integer_5000_digits": _scenario("name: x\nseed: " + "9" * 5000 + "\n"),
    "integer_beyond_63_bits": _scenario("name: x\nseed: 99999999999999999999\n"),
    "hex_integer_huge": _scenario("name: x\nseed: 0x" + "f" * 40 + "\n"),
    "duplicate_key": _scenario("name: x\nseed: 1\nseed: 2\n"),
    "duplicate_nested_key": _scenario("name: x\ncamera:\n  distance: 3\n  distance: 5\n"),
    "nested_40_deep": _scenario("name: x\nsweep: {markers.count: " + "[" * 40 + "]" * 40 + "}\n"),
    "python_tag": _scenario("name: !!python/object/apply:os.getcwd []\n"),
}

OBSTACLE_CASES = {
    "box_around_subject": _scenario("name: x\noccluders:\n  geoms: [{type: box, pos: [0, 0, 1], size: [1, 1, 1]}]\n"),
    "cylinder_through_subject": _scenario("name: x\noccluders:\n  geoms: [{type: cylinder, pos: [0, 0, 1], "
                                          "size: [0.3, 1]}]\n"),
    "size_1e299": _scenario("name: x\noccluders:\n  geoms: [{type: box, pos: [3, 0, 1], size: [1.0e+299, 1, 1]}]\n"),
    "pos_1e299": _scenario("name: x\noccluders:\n  geoms: [{type: box, pos: [1.0e+299, 0, 1], size: [1, 1, 1]}]\n"),
}


def _special_file(kind: str):
    def build(tmp_path, ctx):
        path = tmp_path / f"{kind}.yaml"
        if kind == "fifo":
            os.mkfifo(path)
        elif kind == "dev_zero":
            path.symlink_to("/dev/zero")
        elif kind == "sparse_3gb":
            with open(path, "wb") as fh:
                fh.truncate(3 * 2**30)
        return ["evaluate", str(path), "--results", str(tmp_path / "results")], path
    return build


FILE_CASES = {"scenario_fifo": _special_file("fifo"), "scenario_dev_zero": _special_file("dev_zero"),
              "scenario_sparse_3gb": _special_file("sparse_3gb")}


# Observation files (`harness track`): arrays that are not real numbers, fractional frames, values beyond any
# camera, headers that lie, archives that expand.

def _good_arrays() -> dict:
    return _arrays(_observation())


def _forged_size(path: Path, arrays: dict, size: int) -> None:
    """An archive whose central directory claims ``size`` uncompressed bytes for its first member."""
    import struct

    _npz(path, arrays)
    data = bytearray(path.read_bytes())
    at = data.index(b"PK\x01\x02")
    data[at + 24:at + 28] = struct.pack("<I", size)
    path.write_bytes(bytes(data))


def _lying_header(path: Path, arrays: dict) -> None:
    """A ``flows`` member whose .npy header claims 1e12 rows."""
    import io

    with zipfile.ZipFile(path, "w") as z:
        for name, a in arrays.items():
            buf = io.BytesIO()
            np.save(buf, a)
            raw = buf.getvalue()
            if name == "flows":
                raw = raw.replace(f"({a.shape[0]}, 4)".encode(), b"(1000000000000, 4)")
            z.writestr(name + ".npy", raw)


def _obs(kind: str):
    def build(tmp_path, ctx):
        path = tmp_path / f"{kind}.npz"
        good = _good_arrays()
        flows = good["flows"]
        if kind == "complex_flows":
            _npz(path, good | {"flows": flows.astype(complex)})
        elif kind == "string_flows":
            _npz(path, good | {"flows": flows.astype(str)})
        elif kind == "bool_flows":
            _npz(path, good | {"flows": flows > 100})
        elif kind == "fractional_frame":
            _npz(path, good | {"frame": good["frame"] + 0.5})
        elif kind == "n_frames_62_5":
            _npz(path, good | {"n_frames": np.array(62.5)})
        elif kind == "n_frames_array":
            _npz(path, good | {"n_frames": np.array([5, 5])})
        elif kind == "frame_huge":
            f = good["frame"].astype(float)
            f[-1] = 1e300
            _npz(path, good | {"frame": f})
        elif kind == "nan_principal_point":
            _npz(path, good | {"intrinsics": good["intrinsics"] * np.array([1, 1, 1, 1, np.nan, 1])})
        elif kind == "infinite_focal":
            _npz(path, good | {"intrinsics": good["intrinsics"] * np.array([1, 1, np.inf, 1, 1, 1])})
        elif kind == "focal_1e-300":
            _npz(path, good | {"intrinsics": good["intrinsics"] * np.array([1, 1, 1e-300, 1e-300, 1, 1])})
        elif kind == "image_1e12_px":
            _npz(path, good | {"intrinsics": good["intrinsics"] * np.array([1e12, 1e12, 1, 1, 1, 1])})
        elif kind == "velocity_1e300":
            f = flows.copy()
            f[2, 3] = 1e300
            _npz(path, good | {"flows": f})
        elif kind == "camera_height_1e300":
            n = int(good["n_frames"])
            _npz(path, good | {"gravity": np.tile([0.0, 1.0, 0.0], (n, 1)), "camera_height": np.full(n, 1e300)})
        elif kind == "camera_motion_1e300":
            _npz(path, good | {"camera_motion": np.full((int(good["n_frames"]), 6), 1e300)})
        elif kind == "fps_1e300":
            _npz(path, good | {"fps": np.array(1e300)})
        elif kind == "header_claims_1e12_rows":
            _lying_header(path, good)
        elif kind == "archive_expands_3gb":
            _forged_size(path, good, 3 * 2**30)
        elif kind == "no_flow_at_all":
            Observation(30.0, Intrinsics.from_fov(45.0, 640, 480), [np.empty((0, 4))] * 5).save(path)
        elif kind == "fifo":
            os.mkfifo(path)
        elif kind == "dev_zero":
            path.symlink_to("/dev/zero")
        elif kind == "sparse_1gb":
            with open(path, "wb") as fh:
                fh.truncate(2**30)
        else:
            raise AssertionError(kind)
        return ["track", str(path), "--database", str(ctx["database"]), "--out", str(tmp_path / "est.npz")], path
    return build


OBSERVATION_23 = {k: _obs(k) for k in (
    "complex_flows", "string_flows", "bool_flows", "fractional_frame", "n_frames_62_5", "n_frames_array",
    "frame_huge", "nan_principal_point", "infinite_focal", "focal_1e-300", "image_1e12_px", "velocity_1e300",
    "camera_height_1e300", "camera_motion_1e300", "fps_1e300", "header_claims_1e12_rows", "archive_expands_3gb",
    "no_flow_at_all", "fifo", "dev_zero", "sparse_1gb")}


# The command line: arguments refused before any work, output paths that cannot be written.

def _track(extra: list[str], named: str, setup=None):
    def build(tmp_path, ctx):
        obs = tmp_path / "obs.npz"
        _observation().save(obs)
        if setup is not None:
            setup(tmp_path)
        argv = ["track", str(obs), "--database", str(ctx["database"])]
        return argv + [a.replace("TMP", str(tmp_path)) for a in extra], Path(named.replace("TMP", str(tmp_path)))
    return build


def _evaluate_tiny(extra: list[str], named: str, setup=None):
    def build(tmp_path, ctx):
        path = tmp_path / "tiny.yaml"
        path.write_text(TINY_YAML)
        if setup is not None:
            setup(tmp_path)
        argv = ["evaluate", str(path), "--results", str(tmp_path / "results"), "--quiet"]
        return argv + [a.replace("TMP", str(tmp_path)) for a in extra], Path(named.replace("TMP", str(tmp_path)))
    return build


def _touch(rel: str):
    return lambda tmp_path: (tmp_path / rel).write_text("x")


def _mkdir(rel: str):
    return lambda tmp_path: (tmp_path / rel).mkdir(parents=True)


COMMAND_LINE_CASES = {
    "particles_1e11_text": _track(["--particles", "1e11"], "--particles"),
    "particles_1e11": _track(["--particles", "100000000000"], "particles"),
    "seed_negative": _track(["--seed", "-1"], "--seed"),
    "seed_5000_digits": _track(["--seed", "9" * 5000], "--seed"),
    "out_is_directory": _track(["--out", "TMP/outdir"], "TMP/outdir", _mkdir("outdir")),
    "out_below_a_file": _track(["--out", "TMP/afile/est.npz"], "TMP/afile/est.npz", _touch("afile")),
    "train_out_is_directory": lambda tmp_path, ctx: (
        (tmp_path / "dbdir").mkdir(), (["train-database", "--out", str(tmp_path / "dbdir")], tmp_path / "dbdir"))[1],
    "simulate_truth_below_file": lambda tmp_path, ctx: (
        (tmp_path / "f").write_text("x"), (["simulate", "--class", "walk", "--out", str(tmp_path / "o.npz"),
                                            "--truth", str(tmp_path / "f" / "t.npz")], tmp_path / "f" / "t.npz"))[1],
    "jobs_zero": _evaluate_tiny(["--jobs", "0"], "--jobs"),
    "jobs_100000": _evaluate_tiny(["--jobs", "100000"], "--jobs"),
    "jobs_not_a_number": _evaluate_tiny(["--jobs", "two"], "--jobs"),
}


# Results directories (`harness evaluate` of a valid scenario): what is in the way is refused before any run,
# and a refused journal is left exactly as it was.

_RESULT = "results/tiny"
_RECORD = '{"key": "c000/r000/walk/d008", "hash": "0123456789abcdef", "rows": [{"method": "full"}]}\n'


def _journal(content: bytes):
    def setup(tmp_path):
        (tmp_path / _RESULT).mkdir(parents=True)
        (tmp_path / _RESULT / "runs.jsonl").write_bytes(content)
    return setup


def _results_fifo(tmp_path):
    (tmp_path / _RESULT).mkdir(parents=True)
    os.mkfifo(tmp_path / _RESULT / "runs.jsonl")


def _results_outside(tmp_path):
    (tmp_path / "results").mkdir()
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / _RESULT).symlink_to(tmp_path / "elsewhere")


RESULTS_CASES = {
    "results_is_a_file": _evaluate_tiny([], "TMP/results", _touch("results")),
    "results_below_a_file": _evaluate_tiny(["--results", "TMP/afile/results"], "TMP/afile", _touch("afile")),
    "scenario_dir_is_a_file": _evaluate_tiny([], "TMP/results/tiny", lambda t: (_mkdir("results")(t),
                                                                              _touch(_RESULT)(t))),
    "scenario_dir_outside_results": _evaluate_tiny([], "TMP/results/tiny", _results_outside),
    "journal_is_a_directory": _evaluate_tiny([], "runs.jsonl", _mkdir(_RESULT + "/runs.jsonl")),
    "journal_is_a_fifo": _evaluate_tiny([], "runs.jsonl", _results_fifo),
    "lock_is_a_directory": _evaluate_tiny([], "runs.jsonl.lock", _mkdir(_RESULT + "/runs.jsonl.lock")),
    "report_is_a_directory": _evaluate_tiny([], "report.md", _mkdir(_RESULT + "/report.md")),
    "table_is_a_directory": _evaluate_tiny([], "summary.csv", _mkdir(_RESULT + "/summary.csv")),
    "plots_is_a_file": _evaluate_tiny([], "plots", lambda t: (_mkdir(_RESULT)(t), _touch(_RESULT + "/plots")(t))),
    "cache_is_a_file": _evaluate_tiny([], "cache", lambda t: (_mkdir("results")(t), _touch("results/cache")(t))),
    "journal_random_bytes": _evaluate_tiny([], "runs.jsonl", _journal(np.random.default_rng(3).bytes(3000))),
    "journal_rows_not_a_list": _evaluate_tiny([], "runs.jsonl", _journal(
        b'{"key": "c000/r000/walk/d008", "hash": "x", "rows": 5}\n')),
    "journal_key_a_list": _evaluate_tiny([], "runs.jsonl", _journal(
        b'{"key": ["c000"], "hash": "x", "rows": []}\n')),
    "journal_key_escapes": _evaluate_tiny([], "runs.jsonl", _journal(
        b'{"key": "c000/r000/../d008", "hash": "x", "rows": []}\n')),
    "journal_nested_100k": _evaluate_tiny([], "runs.jsonl", _journal(b"[" * 100_000 + b"]" * 100_000 + b"\n")),
    "journal_huge_number": _evaluate_tiny([], "runs.jsonl", _journal(b'{"key": 1' + b"0" * 5000 + b"}\n")),
    "journal_bad_line_then_torn": _evaluate_tiny([], "runs.jsonl", _journal(
        _RECORD.encode() + b"not json\n" + b'{"key": "c0')),
    "journal_stale_then_torn": _evaluate_tiny([], "runs.jsonl", _journal(_RECORD.encode() + b'{"key": "c0')),
}


# Capture directories: files that lead outside through symbolic links, files that are not files.

CAPTURE_HEADER = "file,format,skeleton,subject,trial,class,start,end,fps\n"


def _capture(rows: str, setup=None, manifest: str = "MANIFEST.csv"):
    def build(tmp_path, ctx):
        capture = tmp_path / "captures"
        capture.mkdir()
        if setup is not None:
            setup(capture, tmp_path)
        else:
            (capture / manifest).write_text(CAPTURE_HEADER + rows)
        path = tmp_path / "capture.yaml"
        path.write_text(f"name: x\ndatabase: {{source: captures, capture_dirs: [{capture}], manifest: {manifest}}}\n"
                        f"test: {{motions: captures, split: none}}\n")
        return ["evaluate", str(path), "--results", str(tmp_path / "results")], capture / manifest
    return build


def _link_row(target: str, name: str = "walk.bvh"):
    def setup(capture, tmp_path):
        (capture / name).symlink_to(target)
        (capture / "MANIFEST.csv").write_text(CAPTURE_HEADER + f"{name},bvh,,1,1,walk,0,10,120\n")
    return setup


def _linked_folder(capture, tmp_path):
    (capture / "sys").symlink_to("/")
    (capture / "MANIFEST.csv").write_text(CAPTURE_HEADER + "sys/etc/passwd,bvh,,1,1,walk,0,10,120\n")


def _manifest_link(capture, tmp_path):
    (tmp_path / "outside.csv").write_text(CAPTURE_HEADER + "a.bvh,bvh,,1,1,walk,0,10,120\n")
    (capture / "MANIFEST.csv").symlink_to(tmp_path / "outside.csv")


def _fifo_row(capture, tmp_path):
    os.mkfifo(capture / "walk.bvh")
    (capture / "MANIFEST.csv").write_text(CAPTURE_HEADER + "walk.bvh,bvh,,1,1,walk,0,10,120\n")


def _huge_row(capture, tmp_path):
    with open(capture / "walk.bvh", "wb") as fh:
        fh.truncate(300 * 2**20)
    (capture / "MANIFEST.csv").write_text(CAPTURE_HEADER + "walk.bvh,bvh,,1,1,walk,0,10,120\n")


CAPTURE_CASES = {
    "row_links_to_a_system_file": _capture("", _link_row("/etc/passwd")),
    "row_links_outside": _capture("", lambda c, t: ((t / "out.bvh").write_text("HIERARCHY\n"),
                                                    _link_row(str(t / "out.bvh"))(c, t))),
    "row_through_a_folder_linked_to_root": _capture("", _linked_folder),
    "manifest_links_outside": _capture("", _manifest_link),
    "row_is_a_fifo": _capture("", _fifo_row),
    "row_is_300mb": _capture("", _huge_row),
    "row_missing_at_load": _capture("absent.bvh,bvh,,1,1,walk,0,10,120\n"),
    "capture_dir_missing": lambda tmp_path, ctx: (
        (tmp_path / "c.yaml").write_text(f"name: x\ndatabase: {{source: captures, capture_dirs: [{tmp_path}/none]}}\n"
                                         "test: {motions: captures, split: none}\n"),
        (["evaluate", str(tmp_path / "c.yaml"), "--results", str(tmp_path / "r")], tmp_path / "c.yaml"))[1],
}


# Messages: a malformed tolerance file is one line naming it.

CI_SCENARIO = Path(__file__).resolve().parents[1] / "scenarios" / "ci.yaml"


def _regress(tolerances: str, baseline: str = '{"scenario": "ci", "metrics": {"full/correct": 0.8}}\n',
             named: str = "tolerances.yaml"):
    def build(tmp_path, ctx):
        (tmp_path / "results" / "ci").mkdir(parents=True)
        (tmp_path / "results" / "ci" / "metrics.json").write_text('{"full/correct": 0.8}\n')
        base = tmp_path / "baseline"
        base.mkdir()
        (base / "metrics.json").write_text(baseline)
        (base / "tolerances.yaml").write_text(tolerances)
        return (["regress", "--no-run", "--scenario", str(CI_SCENARIO), "--results", str(tmp_path / "results"),
                 "--baseline", str(base)], base / named)
    return build


MESSAGE_CASES = {
    "tolerances_not_yaml": _regress("metrics:\n  correct: {kind: higher\n"),
    "tolerances_duplicate_key": _regress("metrics:\n  correct: {kind: higher}\n  correct: {kind: lower}\n"),
    "tolerances_tab_indent": _regress("metrics:\n\tcorrect: {kind: higher}\n"),
    "baseline_metric_not_a_number": _regress("metrics: {}\n", '{"metrics": {"full/correct": "high"}}\n',
                                             "metrics.json"),
    "baseline_nested_deep": _regress("metrics: {}\n", "[" * 100_000 + "]" * 100_000, "metrics.json"),
}

CORPUS_23 = {"paths": PATH_CASES, "sweeps": SWEEP_CASES, "engine": ENGINE_CASES, "sizes": SIZE_CASES,
             "yaml": YAML_CASES, "files": FILE_CASES, "obstacles": OBSTACLE_CASES, "observations": OBSERVATION_23,
             "command_line": COMMAND_LINE_CASES, "results": RESULTS_CASES, "captures": CAPTURE_CASES,
             "messages": MESSAGE_CASES}


@pytest.mark.parametrize("group, case", [(g, c) for g, cases in CORPUS_23.items() for c in sorted(cases)],
                         ids=lambda v: v)
def test_bad_input_is_refused_at_load(group, case, tmp_path, capsys, database_file, monkeypatch):
    from harness.evaluation import pipeline
    from fakes import fake_run

    # Nothing here may reach a run; if one did, it would be this stand-in (and the tree check would fail).
    monkeypatch.setattr(pipeline, "run_one", fake_run)
    argv, named = CORPUS_23[group][case](tmp_path, {"database": database_file})
    err = _check(argv, named, tmp_path, capsys)
    if case == "sweep_20000_values":
        # Refused by the sweep's shape check, before any of its values is validated (a wall-clock bound here
        # failed on a loaded machine; the shape check is what keeps the refusal immediate).
        assert "20000 values, more than" in err, err
    assert "root:x" not in err                   # no file's content is ever printed


def test_read_only_results_are_refused_before_any_work(tmp_path, capsys, monkeypatch):
    """A read-only file system (or, without root, a directory without write permission)."""
    import subprocess

    from harness.evaluation import pipeline
    from fakes import fake_run

    monkeypatch.setattr(pipeline, "run_one", fake_run)
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(TINY_YAML)
    ro = tmp_path / "ro"
    ro.mkdir()
    mounted = False
    if os.geteuid() == 0:       # root writes through permissions: mount a read-only file system instead
        mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(ro)],
                                 capture_output=True).returncode == 0
        if not mounted:
            pytest.skip("running as root without permission to mount a read-only file system")
    else:
        ro.chmod(0o555)
    try:
        _check(["evaluate", str(scenario), "--results", str(ro / "results")], ro, tmp_path, capsys)
        _check(["track", str(scenario), "--database", str(scenario), "--out", str(ro / "est.npz")], ro, tmp_path,
               capsys)
    finally:
        if mounted:
            subprocess.run(["umount", str(ro)], check=True)
        else:
            ro.chmod(0o755)


def test_a_scheduler_that_does_not_answer_is_one_line_and_writes_nothing(tmp_path, capsys, monkeypatch):
    import socket

    pytest.importorskip("dask.distributed")
    from harness.evaluation import runner

    monkeypatch.setattr(runner, "SCHEDULER_TIMEOUT_S", 1.0)
    with socket.socket() as s:          # a port nobody listens on
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    scenario = tmp_path / "tiny.yaml"
    scenario.write_text(TINY_YAML)
    err = _check(["evaluate", str(scenario), "--results", str(tmp_path / "results"), "--scheduler",
                  f"tcp://127.0.0.1:{port}"], Path("--scheduler"), tmp_path, capsys)
    assert "no scheduler answered" in err


# --- the checks ------------------------------------------------------------------------------------------

def _tree(root: Path) -> dict[str, tuple]:
    """Every path under ``root`` with its kind and, for files, size and content hash (a link is not followed:
    a link to ``/`` is not walked, and FIFOs are never opened)."""
    import hashlib
    import stat

    out = {}
    for directory, dirs, files in os.walk(root):
        for name in dirs + files:
            path = Path(directory) / name
            st = path.lstat()
            rel = str(path.relative_to(root))
            if stat.S_ISLNK(st.st_mode):
                out[rel] = ("link", os.readlink(path))
            elif stat.S_ISREG(st.st_mode):
                digest = hashlib.sha256(path.read_bytes()).hexdigest() if st.st_size < 2**25 else st.st_mtime_ns
                out[rel] = ("file", st.st_size, digest)
            else:
                out[rel] = (stat.S_IFMT(st.st_mode),)
    return out


def _check(argv: list[str], named: Path, root: Path, capsys) -> str:
    before = _tree(root)
    capsys.readouterr()
    code = main(argv)
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert code == 2, (code, err)
    assert len(lines) == 1 and lines[0].startswith("error: "), err
    assert "Traceback" not in err and "Error:" not in lines[0].split(":", 2)[1]
    assert str(named) in lines[0] or named.name in lines[0], lines[0]
    assert _tree(root) == before, "something was written or changed"
    return lines[0]


def test_corpus_has_at_least_60_inputs():
    n = len(SCENARIOS) + 2 + len(OBSERVATION_CASES) + len(DATABASE_CASES) + len(CAPTURE_FILES) + len(MANIFESTS)
    assert n >= 60
    # Issue 23: at least 60 more, in every group it names.
    assert sum(len(cases) for cases in CORPUS_23.values()) + 2 >= 60
    assert all(len(cases) >= 3 for cases in CORPUS_23.values())
