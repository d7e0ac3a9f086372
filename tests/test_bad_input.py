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
    "mode_video": "name: x\nobservation: {mode: video}\n",
    "particles_zero": "name: x\nengine: {particles: 0}\n",
    "init_distance_reversed": "name: x\nengine: {init_distance: [5, 2]}\n",
    "engine_noise_negative": "name: x\nengine: {noise_px: -1}\n",
    "engine_outlier_prob": "name: x\nengine: {outlier_prob: 1.5}\n",
    "engine_unknown": "name: x\nengine: {bogus: 1}\n",
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


# --- the checks ------------------------------------------------------------------------------------------

def _tree(root: Path) -> set[str]:
    return {str(p.relative_to(root)) for p in root.rglob("*")}


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
    assert _tree(root) == before, "something was written"
    return lines[0]


def test_corpus_has_at_least_60_inputs():
    n = len(SCENARIOS) + 2 + len(OBSERVATION_CASES) + len(DATABASE_CASES) + len(CAPTURE_FILES) + len(MANIFESTS)
    assert n >= 60
