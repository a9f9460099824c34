"""An articulated mannequin of capsules and spheres, posed by forward kinematics from joint-angle
curves: the moving body of the paper's character scenes (its motion-capture data is not public).

Frame: z up, the character faces +y, +x is its left. Proportions are those of a 1.7 m adult
(segment lengths as fractions of height after the usual anthropometric tables, rounded).

A `Motion` maps time to a `Pose` (root position and heading, and a rotation per joint as three
angles in radians, applied as Rz Ry Rx in the parent's frame). Motions start from the rest pose
at rest and blend into their movement with a quintic smoothstep, so there is no velocity jump
and garments can settle before the fast parts. `Mannequin` is an obstacle (a union of driven
capsules): at each time it poses the skeleton and gives every capsule the velocity of its motion
(central difference of the analytic forward kinematics over 1e-4 s, error O(1e-8) m/s).
A mannequin's `phase` delays its motion's start (crowds that are not in lock-step): until then
the body stands still in the motion's opening pose, so every dancer starts at rest.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from cloth.collision.obstacles import CapsuleUnion

HEIGHT = 1.7  # m

# joint: (parent, offset from the parent joint in the rest pose, m)
SKELETON = {
    "pelvis": (None, (0.0, 0.0, 0.98)),
    "abdomen": ("pelvis", (0.0, 0.0, 0.14)),
    "chest": ("abdomen", (0.0, 0.0, 0.18)),
    "neck": ("chest", (0.0, 0.0, 0.15)),
    "head": ("neck", (0.0, 0.0, 0.15)),
    "shoulder_l": ("chest", (0.19, 0.0, 0.12)),
    "elbow_l": ("shoulder_l", (0.0, 0.0, -0.29)),
    "wrist_l": ("elbow_l", (0.0, 0.0, -0.25)),
    "shoulder_r": ("chest", (-0.19, 0.0, 0.12)),
    "elbow_r": ("shoulder_r", (0.0, 0.0, -0.29)),
    "wrist_r": ("elbow_r", (0.0, 0.0, -0.25)),
    "hip_l": ("pelvis", (0.09, 0.0, -0.05)),
    "knee_l": ("hip_l", (0.0, 0.0, -0.44)),
    "ankle_l": ("knee_l", (0.0, 0.0, -0.43)),
    "hip_r": ("pelvis", (-0.09, 0.0, -0.05)),
    "knee_r": ("hip_r", (0.0, 0.0, -0.44)),
    "ankle_r": ("knee_r", (0.0, 0.0, -0.43)),
}
JOINTS = tuple(SKELETON)

# capsule: (joint it moves with, end a and end b in that joint's frame (m), radius (m))
CAPSULES = {
    "head": ("head", (0.0, 0.01, 0.0), (0.0, 0.01, 0.0), 0.10),
    "neck": ("neck", (0.0, 0.0, 0.0), (0.0, 0.0, 0.08), 0.055),
    "chest": ("chest", (-0.07, 0.0, 0.02), (0.07, 0.0, 0.02), 0.125),
    "abdomen": ("abdomen", (-0.05, 0.0, 0.04), (0.05, 0.0, 0.04), 0.115),
    "pelvis": ("pelvis", (-0.07, 0.0, -0.02), (0.07, 0.0, -0.02), 0.12),
    "upper_arm_l": ("shoulder_l", (0.0, 0.0, 0.0), (0.0, 0.0, -0.29), 0.045),
    "lower_arm_l": ("elbow_l", (0.0, 0.0, 0.0), (0.0, 0.0, -0.25), 0.038),
    "hand_l": ("wrist_l", (0.0, 0.0, -0.02), (0.0, 0.0, -0.12), 0.035),
    "upper_arm_r": ("shoulder_r", (0.0, 0.0, 0.0), (0.0, 0.0, -0.29), 0.045),
    "lower_arm_r": ("elbow_r", (0.0, 0.0, 0.0), (0.0, 0.0, -0.25), 0.038),
    "hand_r": ("wrist_r", (0.0, 0.0, -0.02), (0.0, 0.0, -0.12), 0.035),
    "upper_leg_l": ("hip_l", (0.0, 0.0, 0.0), (0.0, 0.0, -0.44), 0.075),
    "lower_leg_l": ("knee_l", (0.0, 0.0, 0.0), (0.0, 0.0, -0.43), 0.055),
    "foot_l": ("ankle_l", (0.0, -0.03, -0.02), (0.0, 0.15, -0.02), 0.04),
    "upper_leg_r": ("hip_r", (0.0, 0.0, 0.0), (0.0, 0.0, -0.44), 0.075),
    "lower_leg_r": ("knee_r", (0.0, 0.0, 0.0), (0.0, 0.0, -0.43), 0.055),
    "foot_r": ("ankle_r", (0.0, -0.03, -0.02), (0.0, 0.15, -0.02), 0.04),
}
CAPSULE_NAMES = tuple(CAPSULES)
VELOCITY_STEP = 1e-4  # s, central difference of the forward kinematics
# Posed times a mannequin keeps (oldest dropped first): a frame asks for its start and end times
# six times each (steps, remesh, view) and for each substep's once; the pose is a function of time.
POSED_CACHE = 16


def _rot(angles) -> np.ndarray:
    """Rz(az) Ry(ay) Rx(ax) for angles (ax, ay, az) in radians."""
    out = np.empty((3, 3))
    _rot_into(float(angles[0]), float(angles[1]), float(angles[2]), out)
    return out


@njit(cache=True)
def _rot_into(ax, ay, az, out):
    """out = Rz(az) Ry(ay) Rx(ax) (3x3; writes `out`), products in the order of (Rz Ry) Rx."""
    cx, sx, cy, sy, cz, sz = np.cos(ax), np.sin(ax), np.cos(ay), np.sin(ay), np.cos(az), np.sin(az)
    # Rz Ry = [[cz cy, -sz, cz sy], [sz cy, cz, sz sy], [-sy, 0, cy]], then times Rx
    m = ((cz * cy, -sz, cz * sy), (sz * cy, cz, sz * sy), (-sy, 0.0, cy))
    for i in range(3):
        out[i, 0] = m[i][0]
        out[i, 1] = m[i][1] * cx + m[i][2] * sx
        out[i, 2] = -m[i][1] * sx + m[i][2] * cx


@njit(cache=True)
def _mat3_into(A, B, out):
    """out = A B (3x3; writes `out`, which may not be A or B)."""
    for i in range(3):
        for j in range(3):
            out[i, j] = A[i, 0] * B[0, j] + A[i, 1] * B[1, j] + A[i, 2] * B[2, j]


@njit(cache=True)
def _joint_frames(parent, offset, angles, moved, heading, root, R, p):
    """World rotation R (J, 3, 3) and position p (J, 3) of every joint (writes R and p).

    `parent` (J,) is each joint's parent's index (-1 for the root; parents come first),
    `offset` (J, 3) the rest offsets, `angles` (J, 3) the joint angles and `moved` (J,) whether
    any of them is nonzero: a joint at rest takes its parent's rotation as it is."""
    Rj = np.empty((3, 3))
    for j in range(parent.shape[0]):
        q = parent[j]
        if q < 0:
            _rot_into(0.0, 0.0, heading, Rj)
            if moved[j]:
                _rot_into(angles[j, 0], angles[j, 1], angles[j, 2], R[j])
                _mat3_into(Rj, R[j].copy(), R[j])
            else:
                R[j] = Rj
            for a in range(3):
                p[j, a] = offset[j, a] + root[a]
            continue
        if moved[j]:
            _rot_into(angles[j, 0], angles[j, 1], angles[j, 2], Rj)
            _mat3_into(R[q], Rj, R[j])
        else:
            R[j] = R[q]
        for a in range(3):
            p[j, a] = p[q, a] + (R[q, a, 0] * offset[j, 0] + R[q, a, 1] * offset[j, 1] + R[q, a, 2] * offset[j, 2])


@njit(cache=True)
def _capsule_ends(R, p, joint, end_a, end_b, out):
    """(K, 2, 3) world endpoints of capsules on joints `joint` (K,) with local ends `end_a`,
    `end_b` (K, 3), from the joint frames R (J, 3, 3), p (J, 3) (writes `out`)."""
    for k in range(joint.shape[0]):
        j = joint[k]
        for a in range(3):
            out[k, 0, a] = p[j, a] + (R[j, a, 0] * end_a[k, 0] + R[j, a, 1] * end_a[k, 1] + R[j, a, 2] * end_a[k, 2])
            out[k, 1, a] = p[j, a] + (R[j, a, 0] * end_b[k, 0] + R[j, a, 1] * end_b[k, 1] + R[j, a, 2] * end_b[k, 2])


@dataclass
class Pose:
    """Root translation (added to the rest position of the pelvis, m), heading (rad about z) and
    joint angles (rad, (ax, ay, az) per joint; missing joints are at rest)."""

    root: np.ndarray = field(default_factory=lambda: np.zeros(3))
    heading: float = 0.0
    angles: dict = field(default_factory=dict)


# The skeleton and the capsules as arrays, for the kernels (JOINTS and CAPSULE_NAMES order)
_PARENT = np.array([-1 if parent is None else JOINTS.index(parent) for parent, _ in SKELETON.values()], np.int64)
_OFFSET = np.array([offset for _, offset in SKELETON.values()], np.float64)
_CAPSULE_JOINT = np.array([JOINTS.index(c[0]) for c in CAPSULES.values()], np.int64)
_CAPSULE_A = np.array([c[1] for c in CAPSULES.values()], np.float64)
_CAPSULE_B = np.array([c[2] for c in CAPSULES.values()], np.float64)


def joint_frames(pose: Pose) -> tuple[np.ndarray, np.ndarray]:
    """World rotations (J, 3, 3) and positions (J, 3) of the joints (JOINTS order) in `pose`."""
    angles = np.zeros((len(JOINTS), 3))
    for name, a in pose.angles.items():
        angles[JOINTS.index(name)] = a
    moved = np.any(angles != 0.0, axis=1)
    R, p = np.empty((len(JOINTS), 3, 3)), np.empty((len(JOINTS), 3))
    _joint_frames(_PARENT, _OFFSET, angles, moved, float(pose.heading),
                  np.asarray(pose.root, np.float64), R, p)
    return R, p


def forward_kinematics(pose: Pose) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """World (rotation, position) of every joint, by name (:func:`joint_frames`).

    A joint at rest (all its angles 0) takes its parent's rotation as it is, without the product
    by the identity, which would give the same numbers (each entry a * 1 + b * 0 + c * 0 = a)."""
    R, p = joint_frames(pose)
    return {name: (R[j], p[j]) for j, name in enumerate(JOINTS)}


def capsule_endpoints(pose: Pose, frames: dict | None = None) -> np.ndarray:
    """(K, 2, 3) world endpoints of the capsules (CAPSULE_NAMES order); `frames`: the pose's
    forward kinematics when already computed."""
    if frames is None:
        R, p = joint_frames(pose)
    else:
        R = np.stack([frames[name][0] for name in JOINTS])
        p = np.stack([frames[name][1] for name in JOINTS])
    return _ends_of(R, p)


def _ends_of(R: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(K, 2, 3) capsule endpoints from the joint frames R (J, 3, 3), p (J, 3)."""
    ends = np.empty((len(CAPSULES), 2, 3))
    _capsule_ends(R, p, _CAPSULE_JOINT, _CAPSULE_A, _CAPSULE_B, ends)
    return ends


CAPSULE_RADII = np.array([c[3] for c in CAPSULES.values()])


# ---- motions ---------------------------------------------------------------------------------

def smoothstep(x):
    """Quintic 0 -> 1 on [0, 1] with zero first and second derivatives at both ends."""
    x = np.clip(x, 0.0, 1.0)
    return x * x * x * (x * (6 * x - 15) + 10)


class Motion:
    """A pose for every time; subclasses implement `pose(t)`. Deterministic and smooth in t."""

    name = "rest"
    blend_in: float = 1.0  # s from the rest pose to full motion

    def pose(self, t: float) -> Pose:
        return Pose()


class Rest(Motion):
    pass


@dataclass
class Dance(Motion):
    """Turns about the vertical axis, hip sway, raised arms and steps; fast enough that a circle
    skirt flares out (up to `spin_hz` turns per second after the blend-in). The opening pose holds
    the arms out to the sides (`start_arms` rad of shoulder abduction), clear of a skirt's
    starting disc at the waist."""

    name = "dance"
    speed: float = 1.0  # time scale (2 = twice as fast)
    spin_hz: float = 1.0  # turns per second at full motion
    blend_in: float = 1.0  # s
    settle: float = 0.5  # s at rest before the blend-in starts (garments settle)
    start_arms: float = 1.45  # rad, shoulder abduction of the opening pose (~83 degrees)

    def pose(self, t):
        s = self.speed * t
        w = smoothstep((s - self.settle) / self.blend_in)
        # heading: the integral of spin_hz * w(s), so the turn rate ramps up without a jump
        heading = 2 * np.pi * self.spin_hz * _integral_smoothstep(s, self.settle, self.blend_in)
        step = 2 * np.pi * 1.2 * s  # 1.2 steps per second
        sway = 0.25 * np.sin(step)
        lift_l, lift_r = max(np.sin(step), 0.0) ** 2, max(-np.sin(step), 0.0) ** 2
        arms = self.start_arms + (2.4 - self.start_arms) * w  # raised from the opening pose to ~140 degrees
        a = {
            "pelvis": (0.0, 0.15 * w * np.sin(step), sway * w),
            "abdomen": (0.0, -0.1 * w * np.sin(step), -0.5 * sway * w),
            "chest": (0.05 * w * np.sin(2 * step), 0.0, 0.0),
            "shoulder_l": (0.2 * w * np.sin(step), -arms + 0.2 * w * np.sin(step + 1), 0.0),
            "shoulder_r": (0.2 * w * np.sin(step + np.pi), arms + 0.2 * w * np.sin(step + 2), 0.0),
            "elbow_l": (0.0, -0.4 * w, 0.0),
            "elbow_r": (0.0, 0.4 * w, 0.0),
            "hip_l": (-0.5 * w * lift_l, 0.0, 0.0),
            "knee_l": (0.9 * w * lift_l, 0.0, 0.0),
            "hip_r": (-0.5 * w * lift_r, 0.0, 0.0),
            "knee_r": (0.9 * w * lift_r, 0.0, 0.0),
        }
        root = np.array([0.04 * w * np.sin(step), 0.0, -0.03 * w * (1 - np.cos(2 * step)) / 2])
        return Pose(root, heading, a)


@dataclass
class Karate(Motion):
    """Stance, alternating punches, a front kick and a half turn, on a 4 s loop after the blend-in.
    The opening pose (yoi) holds the fists forward at belt height, upper arms `start_shoulder` rad
    forward and elbows `start_elbow` rad bent, so the arms stay above the skirts of the outfit."""

    name = "karate"
    speed: float = 1.0
    blend_in: float = 1.0
    settle: float = 0.5
    start_shoulder: float = 0.6  # rad, upper arms forward in the opening pose
    start_elbow: float = 1.4  # rad, elbows bent in the opening pose

    def pose(self, t):
        s = self.speed * t
        w = smoothstep((s - self.settle) / self.blend_in)
        u = max(s - self.settle - self.blend_in, 0.0) % 4.0  # phase in the 4 s routine
        bump = lambda c, width: smoothstep(1 - abs(u - c) / width)  # noqa: E731  a smooth pulse at c
        punch_l, punch_r = bump(0.5, 0.35), bump(1.2, 0.35)
        kick = bump(2.2, 0.5)
        turn = smoothstep((u - 2.8) / 0.8)  # half turn from 2.8 s to 3.6 s of each loop
        loops = np.floor(max(s - self.settle - self.blend_in, 0.0) / 4.0)
        heading = np.pi * (loops + turn) * w
        sh0, el0 = self.start_shoulder, self.start_elbow
        guard = sh0 + (0.9 - sh0) * w  # upper arms forward: opening pose -> guard
        bend = el0 + (1.6 - el0) * w
        a = {
            "pelvis": (0.0, 0.0, 0.2 * w),
            "chest": (0.0, 0.0, -0.2 * w + 0.3 * (punch_r - punch_l)),
            # a punch raises the arm forward (0.7 rad more) and straightens the elbow
            "shoulder_l": (-(guard + 0.7 * w * punch_l), -0.2 * w, 0.0),
            "elbow_l": (-bend * (1 - w * punch_l), 0.0, 0.0),
            "shoulder_r": (-(guard + 0.7 * w * punch_r), 0.2 * w, 0.0),
            "elbow_r": (-bend * (1 - w * punch_r), 0.0, 0.0),
            # stance: legs apart, knees bent; the kick raises the right thigh and extends the shin
            "hip_l": (-0.3 * w, -0.25 * w, 0.0),
            "knee_l": (0.5 * w, 0.0, 0.0),
            "hip_r": (w * (0.2 - 1.7 * kick), 0.25 * w, 0.0),
            "knee_r": (w * (0.5 + 0.6 * bump(2.0, 0.3) - 0.5 * kick), 0.0, 0.0),
        }
        root = np.array([0.0, 0.0, -0.1 * w])
        return Pose(root, heading, a)


def _integral_smoothstep(s, start, width):
    """Integral over [0, s] of smoothstep((x - start) / width) dx (in seconds)."""
    x = np.clip((s - start) / width, 0.0, 1.0)
    ramp = width * (x ** 6 - 3 * x ** 5 + 2.5 * x ** 4)  # the antiderivative of the quintic
    return ramp + max(s - start - width, 0.0)


MOTIONS = {"rest": Rest, "dance": Dance, "karate": Karate}


def make_motion(name: str, **params) -> Motion:
    if name not in MOTIONS:
        raise ValueError(f"unknown motion {name!r}; known: {sorted(MOTIONS)}")
    return MOTIONS[name](**params)


# ---- the body as an obstacle -------------------------------------------------------------------

def motion_time(t: float, phase: float) -> float:
    """Time of a motion delayed by `phase` seconds, at scene time `t` (s): 0 until t = phase, so
    the body holds its opening pose at rest until its motion starts."""
    return max(float(t) - float(phase), 0.0)


class Mannequin(CapsuleUnion):
    """The posed body as a driven capsule union, placed at `position` (m) facing `heading` (rad),
    with its motion's start delayed by `phase` seconds (>= 0; crowds that are not in lock-step):
    the body stands at rest in the opening pose until t = phase, then moves as the motion from
    its own time 0, so it starts at rest and blends in like an undelayed body."""

    name = "mannequin"

    def __init__(self, motion: Motion, position=(0.0, 0.0, 0.0), heading: float = 0.0, phase: float = 0.0,
                 name=None):
        if not phase >= 0:
            raise ValueError(f"a mannequin's phase is a delay of its motion (s) and must be >= 0, got {phase}")
        self.motion = motion
        self.offset = np.asarray(position, dtype=np.float64)  # m
        self.place_heading = float(heading)  # rad about z
        self.phase = float(phase)  # s, delay of the motion's start
        self._posed = {}  # time -> (capsule endpoints, their velocities): the last POSED_CACHE times
        ends = capsule_endpoints(Pose())
        super().__init__(ends, CAPSULE_RADII, None, name)
        self.motion = motion  # Obstacle's init set a Static motion (for rigid obstacles)
        self.set_time(0.0)

    def pose_at(self, t: float) -> Pose:
        """The motion's pose at scene time t (s), after the delay (unplaced: the body's own frame)."""
        return self.motion.pose(motion_time(t, self.phase))

    def joint_frames_at(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """:func:`joint_frames` of the pose at scene time t, unplaced (the last POSED_CACHE times
        kept: the body's contact and the garments' handles ask for the same times)."""
        key = float(t)
        cache = self.__dict__.setdefault("_joint_frames", {})  # (a checkpoint of a version without it)
        if key not in cache:
            if len(cache) >= 3 * POSED_CACHE:  # each posed time asks for t and t +- VELOCITY_STEP
                cache.pop(next(iter(cache)))
            cache[key] = joint_frames(self.pose_at(t))
        return cache[key]

    def frames_at(self, t: float) -> dict:
        """forward_kinematics of the pose at scene time t, unplaced (:meth:`joint_frames_at`)."""
        R, p = self.joint_frames_at(t)
        return {name: (R[j], p[j]) for j, name in enumerate(JOINTS)}

    def endpoints_at(self, t: float) -> np.ndarray:
        """(K, 2, 3) world capsule endpoints at time t."""
        ends = _ends_of(*self.joint_frames_at(t))
        c, s = np.cos(self.place_heading), np.sin(self.place_heading)
        Rh = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return ends @ Rh.T + self.offset

    def set_time(self, t: float) -> None:
        if not isinstance(self.motion, Motion):  # during CapsuleUnion.__init__
            return super().set_time(t)
        key = float(t)
        posed = self.__dict__.setdefault("_posed", {})  # (a checkpoint of a version without it)
        if key not in posed:  # a frame's boundaries are asked for several times (steps, remesh, view)
            h = VELOCITY_STEP
            ends = self.endpoints_at(t)
            vel = (self.endpoints_at(t + h) - self.endpoints_at(t - h)) / (2 * h)
            if len(posed) >= POSED_CACHE:
                posed.pop(next(iter(posed)))
            posed[key] = (ends, vel)
        ends, vel = (a.copy() for a in posed[key])
        self.R, self.p = np.eye(3), np.zeros(3)
        self.omega, self.v0 = np.zeros(3), np.zeros(3)
        self.set_capsules(ends, vel)

    @property
    def moving(self) -> bool:
        return True
