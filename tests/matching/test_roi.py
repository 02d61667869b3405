"""The object, not the scene: the cameras' region and the support plane cut."""

import numpy as np

from matching.cameras import Camera
from matching.roi import axes_convergence, select_object


def _look_at(centre, target, up=(0.0, 0.0, 1.0), f=800.0, size=(800, 600), name=""):
    z = np.asarray(target, float) - centre
    z /= np.linalg.norm(z)
    x = np.cross(z, up)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)  # image y down: -up
    R = np.array([x, y, z])
    K = np.array([[f, 0, size[0] / 2 - 0.5], [0, f, size[1] / 2 - 0.5], [0, 0, 1.0]])
    return Camera(K=K, dist=np.zeros(0), R=R, t=-R @ centre, width=size[0], height=size[1],
                  name=name)


def _ring(n=12, radius=4.0, height=1.5):
    angles = np.linspace(0, 2 * np.pi, n, endpoint=False)
    return [_look_at(np.array([radius * np.cos(a), radius * np.sin(a), height]), (0, 0, 0),
                     name=f"v{k}") for k, a in enumerate(angles)]


def _scene(rng, noise=0.002):
    """A ball of radius 0.5 on the ground z = -0.5, the ground 10 x 10, a far wall."""
    ball = rng.normal(size=(6000, 3))
    ball = 0.5 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    ground = np.c_[rng.uniform(-5, 5, (8000, 2)), np.full(8000, -0.5)]
    wall = np.c_[rng.uniform(-20, 20, 2000), np.full(2000, 25.0), rng.uniform(-0.5, 10, 2000)]
    points = np.r_[ball, ground, wall] + rng.normal(0, noise, (16000, 3))
    labels = np.repeat([0, 1, 2], [6000, 8000, 2000])
    return points, labels


def test_axes_of_a_ring_meet_at_the_object():
    point, conditioning = axes_convergence(_ring())
    np.testing.assert_allclose(point, 0.0, atol=1e-9)
    assert conditioning > 0.1


def test_ring_keeps_the_ball_and_cuts_ground_and_wall():
    rng = np.random.default_rng(0)
    points, labels = _scene(rng)
    result = select_object(points, _ring(), sigma=np.full(len(points), 0.002))
    assert result.method == "convergence"
    # the ball's points above the ground band (tau = max(3 sigma, 2 spacing)) all stay
    band = result.info["band"]
    above = (labels == 0) & (points[:, 2] > -0.5 + 2 * band)
    assert result.keep[above].all()
    assert result.keep[labels == 0].mean() > 0.97
    assert not result.keep[labels == 2].any()   # the far wall: outside the cameras' ball
    assert result.keep[labels == 1].mean() < 0.01  # the ground: the support plane
    normal = np.array(result.info["plane"][:3])
    assert abs(normal @ [0, 0, 1]) > np.cos(np.radians(1.0))


def test_facade_path_keeps_the_wall_the_cameras_face():
    rng = np.random.default_rng(1)
    # walking past a facade y = 10 (x in -8..8, z in 0..12) with the ground z = 0
    cams = [_look_at(np.array([x, 0.0, 1.6]), (x, 10.0, 1.6), name=f"p{k}")
            for k, x in enumerate(np.linspace(-4, 4, 9))]
    facade = np.c_[rng.uniform(-8, 8, 8000), np.full(8000, 10.0), rng.uniform(0, 12, 8000)]
    ground = np.c_[rng.uniform(-8, 8, 1500), rng.uniform(3, 10, 1500), np.zeros(1500)]
    points = np.r_[facade, ground] + rng.normal(0, 0.005, (9500, 3))
    result = select_object(points, cams, sigma=np.full(len(points), 0.005))
    assert result.method == "path"
    seen = np.zeros(len(points), bool)
    for cam in cams:
        uv = cam.project(points)
        seen |= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width) & (uv[:, 1] >= 0) & (
            uv[:, 1] < cam.height)
    # the facade is a plane the cameras face, never a support plane: what they see above
    # the ground's band stays
    above = seen[:8000] & (points[:8000, 2] > result.info["band"])
    assert result.keep[:8000][above].mean() > 0.97
    # the ground in front of it is the second plane tried, and cut
    assert result.keep[8000:].mean() < 0.01
