import subprocess
import sys

import mujoco
import numpy as np
import pytest

from harness.body import DEFAULT_MODEL_PATH, BodyModel, geom_z_range, sample_surface
from harness.errors import ModelError


def test_structure(body):
    m = body.model
    assert (m.nq, m.nv) == (57, 56)
    assert m.jnt_type[0] == mujoco.mjtJoint.mjJNT_FREE
    assert np.sum(m.jnt_type == mujoco.mjtJoint.mjJNT_HINGE) == 50
    assert len(body.joint_names) == 50 and len(set(body.joint_names)) == 50
    assert np.all(np.isfinite(body.lower)) and np.all(np.isfinite(body.upper))
    assert np.all(body.lower < body.upper)
    assert np.all(body.lower <= 0) and np.all(body.upper >= 0), "the zero pose must be within limits"
    # Human ranges: no hinge moves more than a full half-turn either way.
    assert np.all(np.abs(np.rad2deg(body.lower)) <= 180) and np.all(np.rad2deg(body.upper) <= 180)


def test_naming_scheme(body):
    for name, bid in zip(body.joint_names, body.angle_body):
        assert name.rsplit("_", 1)[0] == body.body_names[bid]
        axis = {"x": [1, 0, 0], "y": [0, 1, 0], "z": [0, 0, 1]}[name.rsplit("_", 1)[1]]
        assert np.allclose(body.model.jnt_axis[body.angle_index(name) + 1], axis)


def test_right_side_mirrors_left(body):
    for name in body.joint_names:
        if name.startswith("l") and name[1:] not in ("owerback_y", "owerback_x", "owerback_z",
                                                      "owerneck_y", "owerneck_x", "owerneck_z"):
            left = body.angle_index(name)
            right = body.angle_index("r" + name[1:])
            if name.endswith("_y"):
                assert body.lower[left] == body.lower[right] and body.upper[left] == body.upper[right]
            else:
                assert np.isclose(body.lower[left], -body.upper[right])
                assert np.isclose(body.upper[left], -body.lower[right])


def test_standing_height_and_floor(body):
    z = geom_z_range(body, body.zero_qpos())
    assert 1.65 <= z[:, 1].max() <= 1.85
    assert z[:, 0].min() >= -1e-9, "a geom of the zero pose is below the floor"
    assert z[:, 0].min() <= 1e-6, "the soles should touch the floor"


def test_geom_z_range_matches_dense_surface_samples(body, rng):
    qpos = body.qpos(body.random_angles(rng, scale=0.6))
    pts = sample_surface(body, 20000, rng, exclude_interior=False)
    from harness.body import forward_points
    world = forward_points(body, qpos, pts.body, pts.local)
    z = geom_z_range(body, qpos)
    for i, g in enumerate(body.body_geoms):
        zs = world[pts.geom == g, 2]
        assert zs.min() >= z[i, 0] - 1e-9 and zs.max() <= z[i, 1] + 1e-9
        assert zs.min() - z[i, 0] < 0.02 and z[i, 1] - zs.max() < 0.02


def test_every_part_is_covered(body):
    names = {mujoco.mj_id2name(body.model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) for g in body.body_geoms}
    for part in ["pelvis", "thorax", "head", "lhumerus", "rradius", "lhand", "rhand", "lfemur", "rtibia",
                 "lfoot", "rfoot"]:
        assert part in names


def test_angle_maps_roundtrip(body, rng):
    angles = body.random_angles(rng, 5)
    q = body.qpos(angles, base_pos=[1.0, 2.0, 3.0])
    assert np.array_equal(body.angles(q), angles)
    assert np.array_equal(q[:, :3], np.tile([1.0, 2.0, 3.0], (5, 1)))
    with pytest.raises(KeyError, match="unknown joint"):
        body.angle_index("lknee")


def test_missing_model_names_the_file(tmp_path):
    with pytest.raises(ModelError, match="no such model file"):
        BodyModel.load(tmp_path / "nope.xml")


def test_malformed_model_is_one_line(tmp_path):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body></mujoco>")
    with pytest.raises(ModelError) as err:
        BodyModel.load(bad)
    assert str(bad) in str(err.value) and "\n" not in str(err.value)


def test_model_without_56_dof_is_rejected(tmp_path):
    small = tmp_path / "small.xml"
    small.write_text("<mujoco><worldbody><body><freejoint/><geom size='.1'/>"
                     "<body><joint type='hinge' range='-1 1'/><geom size='.1'/></body></body>"
                     "</worldbody></mujoco>")
    with pytest.raises(ModelError, match="expected 1 free joint and 50 hinges"):
        BodyModel.load(small)


def test_cli_reports_bad_model_in_one_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "harness", "model-info", "--model", str(tmp_path / "x.xml")],
                          capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.strip().count("\n") == 0 and "no such model file" in proc.stderr
    assert "Traceback" not in proc.stderr


def test_default_model_path_exists():
    assert DEFAULT_MODEL_PATH.is_file()
