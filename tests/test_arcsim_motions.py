"""The motions of an ARCSim config (cloth.io.arcsim_motion): keyframes, their velocities and
rotations, .mot files, checked against poses computed by hand and finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest
from arcsim_configs import (
    C45,
    EXACT,
    FD_STEP,
    FD_TOL,
    MOT,
    arcsim_dir,
    base,
    load,
    rot,
)

from cloth.collision.obstacles import Sphere
from cloth.core.scene import Handle
from cloth.io.arcsim import ArcsimConfigError
from cloth.io.arcsim_motion import ArcsimMotionError, read_mot


@pytest.fixture
def root(tmp_path):
    """An ARCSim-like directory (arcsim_configs.arcsim_dir)."""
    return arcsim_dir(tmp_path)


# ---- motions --------------------------------------------------------------------------------------

def keyframed_config(motions, **changes):
    return base(motions=motions, **changes)



def test_keyframes_are_hermite_with_catmull_rom_tangents_and_clamped(root):
    keys = [{"time": 0, "transform": {"translate": [0, 0, 0]}},
            {"time": 1, "transform": {"translate": [1, 0, 0]}},
            {"time": 3, "transform": {"translate": [5, 0, 0]}}]
    m = load(root, keyframed_config([keys])).motions[0]
    # tangents: 0 at the ends, (5 - 0) / (3 - 0) = 5/3 at t = 1
    x = {t: m.pose(t)[1][0] for t in (-1, 0, 0.5, 1, 2, 3, 10)}
    assert x[-1] == 0 and x[0] == 0 and x[1] == 1 and x[3] == 5 and x[10] == 5  # keys, clamped outside
    assert x[0.5] == pytest.approx(0.5 - 5 / 3 * 0.125, abs=EXACT)  # = 7/24
    assert x[2] == pytest.approx(0.5 + 2.5 + 2 * 5 / 3 * 0.125, abs=EXACT)  # = 41/12
    assert m.velocity(0.5)[1][0] == pytest.approx(1.5 - 5 / 12, abs=EXACT)  # = 13/12
    for t in (-1, 3, 10):  # no motion outside the keys (nor at the last one)
        np.testing.assert_array_equal(m.velocity(t)[1], 0)
    assert m.scale == 1.0


def test_keyframe_velocity_and_the_segment_a_key_time_belongs_to(root):
    keys = [{"time": 0, "velocity": {"translate": [2, 0, 0]}},  # no transform: identity
            {"time": 1, "transform": {"translate": [1, 0, 0]}}]
    m = load(root, keyframed_config([keys])).motions[0]
    assert m.pose(0.5)[1][0] == pytest.approx(0.5 + 2 * 0.125, abs=EXACT)
    assert m.velocity(0)[1][0] == 2  # t = t_0 is in the first segment ...
    assert m.velocity(-1e-9)[1][0] == 0  # ... and before it nothing moves
    np.testing.assert_array_equal(m.key_velocity[:, 0], 0)  # a velocity's default scale 1 reads as 0


def test_rotations_interpolate_as_quaternion_4_vectors_then_normalise(root):
    keys = [{"time": 0}, {"time": 1, "transform": {"rotate": [90, 0, 0, 1]}}]
    m = load(root, keyframed_config([keys])).motions[0]
    # u = 1/4: Hermite weights 27/32 and 5/32 (tangents 0); q = 27/32 (1,0,0,0) + 5/32 (c,0,0,s)
    w0, w1 = 27 / 32, 5 / 32
    angle = math.degrees(2 * math.atan2(w1 * math.sin(math.pi / 4), w0 + w1 * math.cos(math.pi / 4)))
    assert angle == pytest.approx(13.21, abs=0.01)  # not slerp's 5/32 * 90 = 14.06
    R, p = m.pose(0.25)
    np.testing.assert_allclose(R, rot("z", angle), atol=EXACT)
    np.testing.assert_array_equal(p, 0)


def check_velocity_against_poses(m, t):
    """(omega, v0) of a rigid motion against central differences of its poses."""
    (R0, p0), (R1, p1) = m.pose(t - FD_STEP), m.pose(t + FD_STEP)
    R, p = m.pose(t)
    W = (R1 - R0) / (2 * FD_STEP) @ R.T  # [omega]x
    omega, v0 = m.velocity(t)
    np.testing.assert_allclose(omega, [W[2, 1], W[0, 2], W[1, 0]], atol=FD_TOL)
    np.testing.assert_allclose(v0 + np.cross(omega, p), (p1 - p0) / (2 * FD_STEP), atol=FD_TOL)


def test_rigid_velocity_matches_the_poses(root):
    keys = [{"time": 0, "transform": {"translate": [0, 0, 1], "rotate": [0, 1, 0, 0]}},
            {"time": 1, "transform": {"translate": [1, 2, 1], "rotate": [60, 1, 1, 0]}},
            {"time": 2, "transform": {"translate": [0, 1, 0], "rotate": [120, 0, 0, 1]}}]
    m = load(root, keyframed_config([keys])).motions[0]
    for t in (0.3, 1.2, 1.7):
        check_velocity_against_poses(m, t)


def test_constant_scale_is_rigid_and_changing_scale_is_not(root):
    constant = [{"time": t, "transform": {"scale": 0.1, "translate": [0, y, 0]}}
                for t, y in ((0, 0), (1, -1.5), (2, 0))]  # as sphere.json's
    shrink = [{"time": 0}, {"time": 1, "transform": {"scale": 0}}]  # as tshirt.json's handle motions
    conf = load(root, keyframed_config([constant, shrink]))
    sphere_like, shrinking = conf.motions
    assert sphere_like.scale == 0.1
    assert sphere_like.transform_at(0.5).scale == pytest.approx(0.1, abs=EXACT)
    np.testing.assert_allclose(sphere_like.pose(1.0)[1], [0, -1.5, 0])
    assert shrinking.scale is None
    with pytest.raises(ArcsimMotionError, match="transform_at"):
        shrinking.pose(0.5)
    assert shrinking.transform_at(0.25).scale == pytest.approx(27 / 32, abs=EXACT)
    # a body point (1, 0, 0) shrinks towards the origin at ds/dt = 6u^2 - 6u = -1.5 at u = 1/2
    x, v = shrinking.point_velocity([1.0, 0.0, 0.0], 0.5)
    np.testing.assert_allclose(x, [0.5, 0, 0], atol=EXACT)
    np.testing.assert_allclose(v, [-1.5, 0, 0], atol=EXACT)


def test_motions_follow_the_projects_motion_protocol(root):
    keys = [{"time": 0}, {"time": 1, "transform": {"translate": [1, 0, 0], "rotate": [90, 0, 0, 1]}}]
    m = load(root, keyframed_config([keys])).motions[0]
    x = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 1.0]])
    handle = Handle(nodes=np.array([0, 1]), motion=m)
    handle.attach(x)
    np.testing.assert_allclose(handle.targets(0.6), m.carry(x, 0.0, 0.6), atol=EXACT)
    sphere = Sphere(center=(0, 0, 0), radius=0.1, motion=m)
    sphere.set_time(1.0)
    np.testing.assert_allclose(sphere.p, [1, 0, 0], atol=EXACT)


def test_motfile_parts_become_motions(root):
    motions = {"motfile": "meshes/walk.mot", "fps": 2,
               "transform": {"translate": [10, 0, 0], "rotate": [90, 1, 0, 0], "scale": 2}}
    conf = load(root, base(motions=motions))
    assert len(conf.motions) == 2 and conf.motfile.path == root / "meshes" / "walk.mot" and conf.motfile.fps == 2
    part0, part1 = conf.motions
    np.testing.assert_allclose(part0.key_time, [0, 0.5, 1.0])
    assert part0.scale == 2 and part1.scale == 2
    # frame 1 (t = 0.5): world = transform(part frame): p = (10,0,0) + 2 Rx(90) p_part
    R, p = part0.pose(0.5)
    np.testing.assert_allclose(p, [12, 0, 0], atol=EXACT)
    np.testing.assert_allclose(R, rot("x", 90), atol=EXACT)
    R, p = part1.pose(0.5)
    np.testing.assert_allclose(p, [10, -2, 0], atol=EXACT)
    np.testing.assert_allclose(R, rot("x", 90) @ rot("z", 90), atol=EXACT)
    # between frames 1 and 2 (u = 1/2, h = 1/2): the third orientation was flipped to (0,0,0,1);
    # tangent at frame 1 = (q2 - q0) / 1, at frame 2 = 0: q = q1/2 + q2/2 + h (q2 - q0)/8
    q = 0.5 * np.array([C45, 0, 0, C45]) + 0.5 * np.array([0, 0, 0, 1]) + 0.5 / 8 * np.array([-1, 0, 0, 1])
    angle = math.degrees(2 * math.atan2(q[3], q[0]))
    np.testing.assert_allclose(part1.pose(0.75)[0], rot("x", 90) @ rot("z", angle), atol=EXACT)
    assert part1.pose(5.0)[0] == pytest.approx(rot("x", 90) @ rot("z", 180), abs=EXACT)  # clamped
    check_velocity_against_poses(part1, 0.7)


def test_read_mot_arrays_and_errors(tmp_path):
    path = tmp_path / "walk.mot"
    path.write_text(MOT)
    mot = read_mot(path)
    assert (mot.n_parts, mot.n_frames) == (2, 3)
    np.testing.assert_array_equal(mot.part_position[0, :, 0], [0, 1, 2])
    np.testing.assert_array_equal(mot.part_orientation[1, 2], [0, 0, 0, -1])  # as written (w, x, y, z)
    for broken, where in ((MOT.replace("body[1] orientation", "body[2] orientation"), "line 17"),
                          (MOT.replace("0 0 0 -1", "0 0 -1"), "line 20"), ("", "empty"),
                          (MOT.replace("NumFrames: 3", "NumFrames: 4"), "line 6")):
        path.write_text(broken)
        with pytest.raises(ArcsimConfigError, match=where) as info:
            read_mot(path)
        assert str(path) in str(info.value)
