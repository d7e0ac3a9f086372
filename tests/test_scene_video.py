"""Video mode of the scene: the humanoid in cloth, and its flows found by track-video's pipeline."""

import mujoco
import numpy as np
import pytest

from harness.motion.simple_walk import walk_motion
from harness.scene.spec import CameraSpec, ObservationSpec, OccluderSpec, SceneError, SceneSpec
from harness.scene.texture import TEXTURE_NAME, cloth_texture, dress


def test_the_cloth_is_seeded_and_has_corners():
    import cv2

    a = cloth_texture(np.random.default_rng(3))
    assert np.array_equal(a, cloth_texture(np.random.default_rng(3)))
    assert not np.array_equal(a, cloth_texture(np.random.default_rng(4)))
    grey = cv2.cvtColor(a, cv2.COLOR_RGB2GRAY)
    # Shi-Tomasi finds the stripe crossings: at least one per pair of stripes (64 crossings at most 50 px apart).
    corners = cv2.goodFeaturesToTrack(grey, 500, 0.01, 3)
    assert corners is not None and len(corners) >= 64


def test_dressing_covers_the_body_not_the_floor_or_obstacles(body):
    from harness.scene.occluders import Obstacle, add_occluder_geoms

    spec = body.mjspec()
    dress(spec)
    add_occluder_geoms(spec, [Obstacle(np.array([1.5, 0.0, 0.5]), np.array([0.1, 1.0, 0.5]), 0.0)])
    model = spec.compile()
    cloth = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, "cloth")
    body_geoms = np.flatnonzero(model.geom_bodyid > 0)
    world_geoms = np.flatnonzero(model.geom_bodyid == 0)
    assert np.all(model.geom_matid[body_geoms] == cloth)
    assert not np.any(model.geom_matid[world_geoms] == cloth)
    assert mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_TEXTURE, TEXTURE_NAME) >= 0


def test_video_mode_needs_a_static_camera():
    with pytest.raises(SceneError, match="camera.motion"):
        SceneSpec(camera=CameraSpec(motion="orbit", orbit_rate=10.0), observation=ObservationSpec(mode="video"))


def test_video_mode_gives_the_subjects_flows_from_rendered_cloth(body, rng):
    """A short walk seen from the side: the pipeline's flows lie on the subject and move with it (the body's
    surface moves forward, about its speed at the camera's scale), and carry no marker ids."""
    from harness.scene.footage import FEATURE_ID
    from harness.scene.simulate import simulate

    motion = walk_motion(body, 12)
    spec = SceneSpec(camera=CameraSpec(azimuth=90.0), observation=ObservationSpec(mode="video"),
                     occluders=OccluderSpec())
    obs, truth = simulate(motion, spec, rng, body)
    counts = obs.counts
    assert counts[0] == 0 and counts[1:].min() >= 20, counts
    ids = np.concatenate(truth.marker_ids)
    assert np.all(ids == FEATURE_ID)
    rows = np.concatenate(obs.flows[1:])
    # Seen from its left side, the subject walks towards the image's left or right: the torso's flows share a
    # horizontal direction, as the markers' projections do.
    markers_u = np.nanmedian(np.diff(truth.pixels[:, :, 0], axis=0)) * motion.fps
    assert np.sign(np.median(rows[:, 2])) == np.sign(markers_u)
    assert abs(np.median(rows[:, 2]) - markers_u) < 0.5 * abs(markers_u)
    # Every flow lies where the subject is: within the box of its projected markers (plus the limbs' width).
    pix = truth.pixels[1:]
    lo, hi = np.nanmin(pix, axis=(0, 1)) - 20, np.nanmax(pix, axis=(0, 1)) + 20
    assert np.all((rows[:, :2] >= lo) & (rows[:, :2] <= hi))
