"""The conservative culling tests of usd_gs.shadows.shot against brute-force segment tests."""

import numpy as np

from usd_gs.gaussians import GaussianSet
from usd_gs.shadows.shot import occluders_toward, shadow_cone_indices
from usd_gs.usd.lux import ShotLight

RNG = np.random.default_rng(4)


def blob(centre, n=200, spread=0.3):
    p = np.asarray(centre) + RNG.normal(scale=spread, size=(n, 3))
    return GaussianSet(p, np.tile([1.0, 0, 0, 0], (n, 1)), np.full((n, 3), 0.02), np.full(n, 0.9),
                       np.zeros((n, 1, 3)))


def segment_hits_sphere(a, b, c, r):
    """(N,) bool: segment a -> b[i] passes within r of c."""
    d = b - a
    t = np.clip(((c - a) @ d.T) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
    closest = a + t[:, None] * d
    return np.linalg.norm(closest - c, axis=1) <= r


def test_shadow_cone_keeps_every_receiver_a_ray_through_the_caster_reaches():
    occ = blob([0.0, 1.0, 0.0])
    light = ShotLight("l", "point", np.array([0.5, 3.0, 0.2]))
    pts = RNG.uniform(-4, 4, size=(20000, 3))
    ext = occ.extent(3.0).astype(np.float64)
    c, r = 0.5 * (ext[0] + ext[1]), 0.5 * np.linalg.norm(ext[1] - ext[0])
    must = segment_hits_sphere(light.position, pts, c, r)
    got = np.zeros(len(pts), bool)
    got[shadow_cone_indices(occ, pts, light)] = True
    assert must.sum() > 500 and np.all(got[must])  # conservative
    assert got.sum() <= 1.3 * must.sum()  # and not much more than needed


def test_directional_cylinder_is_conservative():
    occ = blob([0.0, 1.0, 0.0])
    light = ShotLight("sun", "directional", direction=np.array([0.3, -1.0, 0.1]))
    pts = RNG.uniform(-4, 4, size=(20000, 3))
    ext = occ.extent(3.0).astype(np.float64)
    c, r = 0.5 * (ext[0] + ext[1]), 0.5 * np.linalg.norm(ext[1] - ext[0])
    far = pts - 100.0 * light.direction / np.linalg.norm(light.direction)  # "light" far up-beam of each point
    must = np.array([segment_hits_sphere(f, p[None], c, r)[0] for f, p in zip(far, pts, strict=True)])
    got = np.zeros(len(pts), bool)
    got[shadow_cone_indices(occ, pts, light)] = True
    assert must.sum() > 500 and np.all(got[must])


def test_occluders_toward_keeps_every_occluder_between_light_and_receivers():
    receivers = blob([2.0, 0.5, -1.0], n=300, spread=0.2).positions
    scene = GaussianSet(RNG.uniform(-4, 4, size=(20000, 3)), np.tile([1.0, 0, 0, 0], (20000, 1)),
                        np.full((20000, 3), 0.01), np.full(20000, 0.9), np.zeros((20000, 1, 3)))
    light = ShotLight("l", "point", np.array([-2.0, 2.5, 1.0]))
    keep = np.zeros(scene.count, bool)
    keep[occluders_toward(scene, receivers, light)] = True
    # every occluder whose 3-sigma sphere touches a light -> receiver segment must be kept
    reach = 3 * 0.01
    sample = receivers[RNG.choice(len(receivers), 60, replace=False)]
    must = np.zeros(scene.count, bool)
    for x in sample:
        d = x - light.position
        t = np.clip(((scene.positions - light.position) @ d) / (d @ d), 0, 1)
        closest = light.position + t[:, None] * d
        must |= np.linalg.norm(scene.positions - closest, axis=1) <= reach
    assert must.sum() > 20 and np.all(keep[must])
    assert keep.sum() < 0.2 * scene.count  # the culling does cull
