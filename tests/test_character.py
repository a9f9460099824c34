"""The mannequin: proportions, rigid forward kinematics, motions that start from rest and are
smooth in time, capsule velocities consistent with the motion, the body as an obstacle, and a
phase that delays the motion (the body at rest until then)."""

import numpy as np
import pytest

from cloth.scenes.character import (
    CAPSULE_NAMES,
    CAPSULE_RADII,
    CAPSULES,
    HEIGHT,
    JOINTS,
    SKELETON,
    Dance,
    Karate,
    Mannequin,
    Pose,
    capsule_endpoints,
    forward_kinematics,
    make_motion,
)

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

ROUNDOFF = 1e-9
# The capsule velocities are central differences over 1e-4 s; over a 1e-3 s window the mean
# velocity (from positions) agrees with them to (accel + jerk) x step^2 ~ 1e-4 m/s.
VELOCITY_TOL = 1e-3
# "No velocity jumps": between samples 1 ms apart the capsule velocities change by at most
# max acceleration x 1 ms; at speed 1 the motions' accelerations stay below 200 m/s^2 (a punch,
# a kick, the blend-in of the raised arms), at speed s below s^2 times that. A jump (a kink in a
# joint-angle curve) would show as a change of the order of the velocity itself (metres/second).
MAX_DV_PER_MS = 0.2
# The kernel's forward kinematics against the numpy definition: 3x3 products summed in another
# order (BLAS against the kernel's loops), a few ulps of 1 m through a chain of 5 joints.
FK_KERNEL_ATOL = 1e-14


def _rot_numpy(angles):
    ax, ay, az = angles
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    Rx = np.array([[1, 0, 0], [0, cx, -sx], [0, sx, cx]])
    Ry = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    Rz = np.array([[cz, -sz, 0], [sz, cz, 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def _forward_kinematics_numpy(pose):
    """The definition: each joint's frame is its parent's times its own rotation, its position
    the parent's plus the parent's rotation of its rest offset; the root turned by the heading."""
    out = {}
    for name, (parent, offset) in SKELETON.items():
        R_own = _rot_numpy(pose.angles.get(name, (0.0, 0.0, 0.0)))
        if parent is None:
            out[name] = (_rot_numpy((0.0, 0.0, pose.heading)) @ R_own, np.asarray(offset, float) + pose.root)
        else:
            Rp, pp = out[parent]
            out[name] = (Rp @ R_own, pp + Rp @ np.asarray(offset, float))
    return out


def test_rest_pose_has_human_proportions():
    ends = capsule_endpoints(Pose())
    bottom = (ends[..., 2] - CAPSULE_RADII[:, None]).min()
    top = (ends[..., 2] + CAPSULE_RADII[:, None]).max()
    assert bottom == pytest.approx(0.0, abs=0.005)
    assert top == pytest.approx(HEIGHT, abs=0.01)
    k = {n: i for i, n in enumerate(CAPSULE_NAMES)}
    assert set(k) >= {"head", "neck", "chest", "abdomen", "pelvis", "upper_arm_l", "lower_arm_r", "hand_l",
                      "upper_leg_r", "lower_leg_l", "foot_r"}
    leg = np.linalg.norm(ends[k["upper_leg_l"], 1] - ends[k["upper_leg_l"], 0]) + \
        np.linalg.norm(ends[k["lower_leg_l"], 1] - ends[k["lower_leg_l"], 0])
    arm = np.linalg.norm(ends[k["upper_arm_r"], 1] - ends[k["upper_arm_r"], 0]) + \
        np.linalg.norm(ends[k["lower_arm_r"], 1] - ends[k["lower_arm_r"], 0])
    assert 0.48 * HEIGHT < leg + 0.06 < 0.56 * HEIGHT  # leg length ~ half the height
    assert 0.30 * HEIGHT < arm < 0.36 * HEIGHT


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_forward_kinematics_kernel_equals_its_numpy_definition(seed):
    rng = np.random.default_rng(seed)
    moved = [j for j in JOINTS if rng.uniform() < 0.6]  # some joints at rest, the root among either
    pose = Pose(rng.normal(size=3), rng.uniform(-np.pi, np.pi), {j: tuple(rng.uniform(-2, 2, 3)) for j in moved})
    frames, want = forward_kinematics(pose), _forward_kinematics_numpy(pose)
    for name in JOINTS:
        assert np.allclose(frames[name][0], want[name][0], rtol=0, atol=FK_KERNEL_ATOL), name
        assert np.allclose(frames[name][1], want[name][1], rtol=0, atol=FK_KERNEL_ATOL), name
    ends = capsule_endpoints(pose)
    for k, (joint, a, b, _) in enumerate(CAPSULES.values()):
        R, p = want[joint]
        assert np.allclose(ends[k], [p + R @ np.asarray(a), p + R @ np.asarray(b)], rtol=0, atol=FK_KERNEL_ATOL)
    assert np.array_equal(capsule_endpoints(pose, frames), ends)  # from precomputed frames: the same


def test_mannequin_endpoints_follow_its_joint_frames():
    body = Mannequin(Dance(), position=(0.3, -0.2, 0.0), heading=0.7, phase=0.2)
    for t in (0.0, 0.9, 1.7, 1.7):  # the last again: from the cache
        R, p = body.joint_frames_at(t)
        frames = body.frames_at(t)
        assert all(np.array_equal(frames[n][0], R[j]) and np.array_equal(frames[n][1], p[j])
                   for j, n in enumerate(JOINTS))
        c, s = np.cos(0.7), np.sin(0.7)
        place = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        want = capsule_endpoints(body.pose_at(t)) @ place.T + np.array([0.3, -0.2, 0.0])
        assert np.allclose(body.endpoints_at(t), want, rtol=0, atol=FK_KERNEL_ATOL)


def test_forward_kinematics_is_rigid_per_segment():
    rest = capsule_endpoints(Pose())
    rng = np.random.default_rng(0)
    pose = Pose(rng.normal(size=3), 1.3, {j: tuple(rng.uniform(-1, 1, 3)) for j in JOINTS})
    posed = capsule_endpoints(pose)
    assert np.allclose(np.linalg.norm(posed[:, 1] - posed[:, 0], axis=1),
                       np.linalg.norm(rest[:, 1] - rest[:, 0], axis=1), atol=ROUNDOFF)
    assert not np.allclose(posed, rest)


@pytest.mark.parametrize("motion", [Dance(), Karate(), Dance(speed=2.0), Karate(speed=2.0)])
def test_motions_start_at_rest_and_are_smooth(motion):
    m = Mannequin(motion)
    m.set_time(0.0)
    assert np.allclose(m.ends, capsule_endpoints(motion.pose(0.0)), atol=ROUNDOFF)
    assert np.abs(m.end_velocities).max() < ROUNDOFF
    prev = None
    speed = motion.speed
    for t in np.arange(0.0, 6.0 / speed, 1e-3):
        m.set_time(t)
        if prev is not None:
            assert np.abs(m.end_velocities - prev).max() < MAX_DV_PER_MS * speed ** 2, t
        prev = m.end_velocities.copy()


@pytest.mark.parametrize("motion", [Dance(), Karate()])
def test_capsule_velocities_are_the_motion_s(motion):
    m = Mannequin(motion, position=(1.0, 2.0, 0.0), heading=0.7, phase=0.3)
    for t in (1.3, 2.25, 3.9):
        dt = 1e-3
        m.set_time(t - dt / 2)
        a = m.ends.copy()
        m.set_time(t + dt / 2)
        b = m.ends.copy()
        m.set_time(t)
        assert np.allclose(m.end_velocities, (b - a) / dt, atol=VELOCITY_TOL)


def test_dance_spins_fast_enough_to_flare_a_skirt():
    m = Mannequin(Dance())
    m.set_time(3.0)  # after the blend-in
    k = CAPSULE_NAMES.index("pelvis")
    # the hip's surface at radius ~0.19 m moves at 2 pi r f ~ 1.2 m/s: enough for a skirt to flare
    surface_speed = np.linalg.norm(m.end_velocities[k], axis=1).max()
    assert surface_speed > 0.3
    heading_rate = 2 * np.pi * Dance().spin_hz
    assert heading_rate >= 2 * np.pi * 0.9


def test_mannequin_is_a_moving_obstacle_with_surface_velocity():
    m = Mannequin(Karate(), position=(0.5, 0.0, 0.0))
    m.set_time(2.7)  # mid-routine
    k = CAPSULE_NAMES.index("lower_arm_l")
    mid = m.ends[k].mean(axis=0)
    outward = np.cross(m.ends[k, 1] - m.ends[k, 0], [0.0, 0.0, 1.0])
    outward /= np.linalg.norm(outward)
    p = mid + (CAPSULE_RADII[k] - 0.01) * outward  # 1 cm inside the forearm
    phi, normal, vel = m.query(p[None])
    assert phi[0] < 0
    assert np.allclose(vel[0], m.end_velocities[k].mean(axis=0), atol=1e-9)
    assert m.moving


@pytest.mark.parametrize("motion", [Dance(), Karate()])
def test_a_phase_delays_the_motion_and_runs_are_deterministic(motion):
    a, b = Mannequin(motion, phase=0.5), Mannequin(motion)
    a.set_time(2.5)
    b.set_time(2.0)
    assert np.allclose(a.ends, b.ends, atol=ROUNDOFF)  # phase seconds late
    assert np.allclose(a.end_velocities, b.end_velocities, atol=ROUNDOFF)
    for t in (0.0, 0.3, 0.5):  # until its start: at rest in the opening pose
        a.set_time(t)
        assert np.allclose(a.ends, capsule_endpoints(motion.pose(0.0)), atol=ROUNDOFF)
        assert np.abs(a.end_velocities).max() < ROUNDOFF
    c = Mannequin(motion, phase=0.5)
    c.set_time(2.0)
    a.set_time(2.0)
    assert np.array_equal(a.ends, c.ends)
    with pytest.raises(ValueError, match="phase"):
        Mannequin(motion, phase=-0.1)
    with pytest.raises(ValueError, match="unknown motion"):
        make_motion("waltz")


def test_a_mannequin_posed_again_at_a_time_it_kept_is_posed_exactly_as_anew():
    """set_time keeps the last POSED_CACHE times' capsules: asking again for a kept time (a frame's
    ends, asked for by its steps, remesh and view), or for a time dropped from the cache, gives
    exactly the capsules a fresh mannequin gets, and changing the capsules does not change the kept ones."""
    from cloth.scenes.character import POSED_CACHE

    cached = Mannequin(Karate(), position=(0.5, 0.2, 0.0), heading=0.3, phase=0.1)
    times = [0.2 + 0.005 * k for k in range(POSED_CACHE + 5)]
    for t in times + times[::-1] + [times[0], times[-1]] * 3:
        cached.set_time(t)
        cached.ends += 1.0  # a caller that writes into the capsules
        cached.set_time(t)
        fresh = Mannequin(Karate(), position=(0.5, 0.2, 0.0), heading=0.3, phase=0.1)
        fresh.set_time(t)
        assert np.array_equal(cached.ends, fresh.ends) and np.array_equal(cached.end_velocities, fresh.end_velocities)
    assert len(cached._posed) == POSED_CACHE


def test_forward_kinematics_of_the_motions_and_its_cache_by_time():
    """The motions' poses leave joints at rest (their rotation is the parent's, no product by the
    identity), and the mannequin keeps each time's kinematics for its contact and its garments'
    handles: the numbers of the product chain (the numpy definition, to FK_KERNEL_ATOL), and of
    the cache the same to the last bit."""
    body = Mannequin(Karate(), position=(1.0, 2.0, 0.0), heading=0.7)
    for t in np.linspace(0.0, 6.0, 31):
        pose = body.pose_at(t)
        assert any(not any(a) for a in pose.angles.values()) or len(pose.angles) < len(SKELETON)
        fast, slow = forward_kinematics(pose), _forward_kinematics_numpy(pose)
        for name in SKELETON:
            assert np.allclose(fast[name][0], slow[name][0], rtol=0, atol=FK_KERNEL_ATOL)
            assert np.allclose(fast[name][1], slow[name][1], rtol=0, atol=FK_KERNEL_ATOL)
        assert body.joint_frames_at(t) is body.joint_frames_at(t)
        cached = body.frames_at(t)
        assert all(np.array_equal(cached[k][0], fast[k][0]) and np.array_equal(cached[k][1], fast[k][1])
                   for k in SKELETON)
        assert np.array_equal(body.endpoints_at(t), capsule_endpoints(pose) @ np.array(
            [[np.cos(0.7), np.sin(0.7), 0.0], [-np.sin(0.7), np.cos(0.7), 0.0], [0.0, 0.0, 1.0]]) + [1.0, 2.0, 0.0])
