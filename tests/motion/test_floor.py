"""Lowest body point per frame (motion.floor.lowest_points) against skinning each frame."""
import numpy as np
from scipy.spatial.transform import Rotation

from wearfit_usd.motion.floor import lowest_points
from wearfit_usd.motion.skinning import skin_points, skinning_matrices


def test_lowest_points_match_skinning_each_frame():
    rng = np.random.default_rng(2)
    n, j, f = 200, 4, 9
    pts = rng.normal(size=(n, 3))
    ji = rng.integers(0, j, (n, 2))
    jw = rng.dirichlet(np.ones(2), size=n)
    bind = np.tile(np.eye(4), (j, 1, 1))
    bind[:, 3, :3] = rng.normal(size=(j, 3))
    world = np.tile(np.eye(4), (f, j, 1, 1))
    world[:, :, :3, :3] = Rotation.random(f * j, random_state=3).as_matrix().reshape(f, j, 3, 3)
    world[:, :, 3, :3] = rng.normal(size=(f, j, 3))
    frames = [0, 3, 8]
    got = lowest_points(pts, ji, jw, bind, world, frames)
    want = [skin_points(pts, ji, jw, skinning_matrices(bind, world[i]))[:, 1].min() for i in frames]
    assert np.allclose(got, want)
    assert np.ptp(got) > 0.1  # the frames differ
    assert lowest_points(pts, ji, jw, bind, world, []).shape == (0,)
