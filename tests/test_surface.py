import mujoco
import numpy as np
import pytest
from scipy import stats

from harness.body import sample_surface
from harness.body.surface import BOX, CAPSULE, CYLINDER, SPHERE, _sample_geom, even_surface, geom_area, geom_sdf


def _in_geom_frame(body, points):
    """Sample positions and normals in their geom's frame."""
    m = body.model
    pos = np.empty_like(points.local)
    nrm = np.empty_like(points.normal)
    for i, g in enumerate(points.geom):
        rot = np.empty(9)
        mujoco.mju_quat2Mat(rot, m.geom_quat[g])
        rot = rot.reshape(3, 3)
        pos[i] = rot.T @ (points.local[i] - m.geom_pos[g])
        nrm[i] = rot.T @ points.normal[i]
    return pos, nrm


@pytest.mark.parametrize("exclude", [False, True])
def test_samples_on_surface_with_unit_outward_normals(body, exclude):
    pts = sample_surface(body, 3000, np.random.default_rng(1), exclude_interior=exclude)
    assert len(pts) == 3000
    pos, nrm = _in_geom_frame(body, pts)
    m = body.model
    for g in np.unique(pts.geom):
        sel = pts.geom == g
        gt, size = int(m.geom_type[g]), m.geom_size[g]
        assert np.max(np.abs(geom_sdf(gt, size, pos[sel]))) < 1e-9
        np.testing.assert_allclose(np.linalg.norm(nrm[sel], axis=1), 1.0, atol=1e-12)
        eps = 1e-7  # small enough that no sample lies within eps of a box edge
        assert np.all(geom_sdf(gt, size, pos[sel] + eps * nrm[sel]) > 0.5 * eps)
        assert np.all(geom_sdf(gt, size, pos[sel] - eps * nrm[sel]) < -0.5 * eps)


def test_density_per_geom_is_proportional_to_area(body):
    pts = sample_surface(body, 6000, np.random.default_rng(2), exclude_interior=False)
    m = body.model
    geoms = body.body_geoms
    counts = np.array([(pts.geom == g).sum() for g in geoms])
    area = np.array([geom_area(int(m.geom_type[g]), m.geom_size[g]) for g in geoms])
    expected = len(pts) * area / area.sum()
    assert stats.chisquare(counts, expected).pvalue > 1e-3
    # The same test rejects a sampler that ignored area (equal counts per geom): it has power.
    equal = np.full(len(geoms), len(pts) / len(geoms))
    assert stats.chisquare(counts, equal).pvalue < 1e-6


@pytest.mark.parametrize("gtype,size", [(SPHERE, [0.1, 0, 0]), (CAPSULE, [0.05, 0.2, 0]),
                                        (BOX, [0.1, 0.03, 0.2]), (CYLINDER, [0.08, 0.1, 0])])
def test_uniform_within_a_geom(gtype, size):
    """Fraction of samples in a slab of the geom equals the slab's share of the area (closed forms)."""
    size = np.array(size, float)
    n = 20000
    pos, _ = _sample_geom(gtype, size, n, np.random.default_rng(3))
    total = geom_area(gtype, size)
    if gtype == SPHERE:        # Archimedes: a slab of height dz has area 2 pi r dz
        share, inside = 2 * np.pi * size[0] * size[0] / total, pos[:, 2] > 0
    elif gtype == CAPSULE:     # the cylindrical side
        share, inside = 4 * np.pi * size[0] * size[1] / total, np.abs(pos[:, 2]) < size[1] - 1e-12
    elif gtype == BOX:         # the two faces normal to z
        share, inside = 8 * size[0] * size[1] / total, np.isclose(np.abs(pos[:, 2]), size[2])
    else:                      # the two end disks
        share, inside = 2 * np.pi * size[0] ** 2 / total, np.isclose(np.abs(pos[:, 2]), size[1])
    k = int(inside.sum())
    assert stats.binomtest(k, n, share).pvalue > 1e-3


def test_interior_points_are_excluded(body):
    pts = sample_surface(body, 4000, np.random.default_rng(4), exclude_interior=True)
    m, d = body.model, mujoco.MjData(body.model)
    mujoco.mj_kinematics(m, d)
    world = d.xpos[pts.body] + np.einsum("pij,pj->pi", d.xmat[pts.body].reshape(-1, 3, 3), pts.local)
    for g in body.body_geoms:
        rel = (world - d.geom_xpos[g]) @ d.geom_xmat[g].reshape(3, 3)
        sdf = geom_sdf(int(m.geom_type[g]), m.geom_size[g], rel)
        assert np.all((sdf > -1e-6) | (pts.geom == g))
    # And some exist to exclude: without the filter, a fair share of samples is buried.
    raw = sample_surface(body, 4000, np.random.default_rng(4), exclude_interior=False)
    world = d.xpos[raw.body] + np.einsum("pij,pj->pi", d.xmat[raw.body].reshape(-1, 3, 3), raw.local)
    buried = np.zeros(len(raw), bool)
    for g in body.body_geoms:
        rel = (world - d.geom_xpos[g]) @ d.geom_xmat[g].reshape(3, 3)
        buried |= (geom_sdf(int(m.geom_type[g]), m.geom_size[g], rel) < -1e-6) & (raw.geom != g)
    assert buried.mean() > 0.02


def test_deterministic_for_a_generator(body):
    a = sample_surface(body, 500, np.random.default_rng(9))
    b = sample_surface(body, 500, np.random.default_rng(9))
    c = sample_surface(body, 500, np.random.default_rng(10))
    assert np.array_equal(a.local, b.local) and np.array_equal(a.geom, b.geom)
    assert not np.array_equal(a.local, c.local)


def test_zero_and_negative_counts(body):
    assert len(sample_surface(body, 0, np.random.default_rng(0))) == 0
    with pytest.raises(ValueError, match=">= 0"):
        sample_surface(body, -1, np.random.default_rng(0))


def test_even_surface_shares_and_covering(body):
    """The engine's evenly spread sample: each geom holds its share of the exposed surface (estimated
    independently from a large area-uniform sample) up to the rounding and the candidates' sampling noise, and
    within each geom farthest-point selection leaves no candidate farther from the chosen points than the
    chosen points are from each other (the greedy rule's covering guarantee)."""
    n, oversample, seed = 150, 8, 11
    pts = even_surface(body, n, np.random.default_rng(seed), oversample=oversample)
    assert len(pts) == n and len(np.unique(pts.local, axis=0)) == n
    reference = sample_surface(body, 40000, np.random.default_rng(12))
    for g in body.body_geoms:
        share = np.mean(reference.geom == g)
        # Rounding (1) plus three standard deviations of a count estimated from n * oversample candidates.
        margin = 1.0 + 3.0 * np.sqrt(n * share * (1.0 - share) / oversample)
        assert abs(np.sum(pts.geom == g) - n * share) <= margin
    candidates = sample_surface(body, oversample * n, np.random.default_rng(seed))   # the same draw
    for g in np.unique(pts.geom):
        chosen = pts.local[pts.geom == g]
        if len(chosen) < 2:
            continue
        mine = candidates.local[candidates.geom == g]
        covering = np.max(np.min(np.linalg.norm(mine[:, None] - chosen[None], axis=2), axis=1))
        pairwise = np.linalg.norm(chosen[:, None] - chosen[None], axis=2)
        assert covering <= np.min(pairwise[np.triu_indices(len(chosen), 1)]) + 1e-12
    # The same generator gives the same points.
    again = even_surface(body, n, np.random.default_rng(seed), oversample=oversample)
    np.testing.assert_array_equal(again.local, pts.local)
