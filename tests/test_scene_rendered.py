"""Scene, rendered mode: the renderer agrees with the geometry (projection, visibility, flows)."""

import numpy as np
import pytest
from scene_motions import walk_motion

from harness.scene import rendered
from harness.scene.simulate import build_setup, simulate
from harness.scene.spec import CameraSpec, ObservationSpec, OccluderSpec, SceneSpec
from harness.scene.visibility import OUTSIDE, VISIBLE


@pytest.fixture(scope="module")
def walk(body):
    return walk_motion(body, 6)


def test_detected_dots_sit_on_projected_markers(body, walk):
    setup = build_setup(walk, SceneSpec(camera=CameraSpec(azimuth=30.0)), body)
    vis = setup.visibility == VISIBLE
    errors, n_vis = [], 0
    for t, rgb in enumerate(rendered.render_frames(setup, walk.qpos[:3])):
        dots = rendered.detect_dots(rendered.greenness(rgb))
        ids = rendered.match_markers(dots, setup.pixels[t], vis[t])
        errors.append(np.linalg.norm(dots[ids >= 0] - setup.pixels[t, ids[ids >= 0]], axis=1))
        n_vis += vis[t].sum()
    e = np.concatenate(errors)
    assert len(e) > 0.8 * n_vis
    assert np.median(e) <= 1.0 and np.percentile(e, 95) <= 2.0


def test_depth_buffer_agrees_with_ray_casting(body, walk):
    setup = build_setup(walk, SceneSpec(camera=CameraSpec(azimuth=120.0),
                                        occluders=OccluderSpec("low_wall", 0.3)), body)
    depth_vis = rendered.depth_visible(setup, walk.qpos)
    inside = setup.visibility != OUTSIDE
    agree = (depth_vis == (setup.visibility == VISIBLE))[inside]
    assert agree.mean() > 0.93
    # The obstacle-hidden markers are hidden in the depth buffer too.
    hidden = setup.visibility == 3
    assert hidden.any() and (~depth_vis[hidden]).mean() > 0.95


def test_rendered_flows_agree_with_geometric_flows(body, walk):
    geo = SceneSpec(camera=CameraSpec(azimuth=30.0), observation=ObservationSpec(noise_px=0.0))
    ren = SceneSpec(camera=CameraSpec(azimuth=30.0), observation=ObservationSpec(mode="rendered", noise_px=0.0))
    obs_g, tg = simulate(walk, geo, np.random.default_rng(0), body)
    obs_r, tr = simulate(walk, ren, np.random.default_rng(0), body)
    obs_r.validate()
    errors, total = [], 0
    for t in range(1, len(walk.qpos)):
        gi_ids, ri_ids = tg.marker_ids[t], tr.marker_ids[t]
        total += len(gi_ids)
        _, gi, ri = np.intersect1d(gi_ids, ri_ids, return_indices=True)
        errors.append(np.linalg.norm(obs_g.flows[t][gi, 2:] - obs_r.flows[t][ri, 2:], axis=1) / walk.fps)
    e = np.concatenate(errors)
    assert len(e) >= 0.8 * total
    assert np.median(e) <= 0.5
