"""Obstacle bodies as triangle meshes: the mannequin's capsules tessellated and skinned to its
joints, and an icosphere (still or moving through keyframes) for tests and the mesh_obstacle scene.
"""

from __future__ import annotations

import numpy as np
import trimesh.creation

from cloth.collision.meshobstacle import TriangleMeshObstacle
from cloth.collision.obstacles import capsule_tessellation
from cloth.scenes.character import CAPSULES, JOINTS, joint_frames, motion_time


# procedural meshes
def icosphere(radius: float = 1.0, subdivisions: int = 2, center=(0.0, 0.0, 0.0)):
    """(vertices (V, 3), faces (F, 3)) of a subdivided icosahedron on a sphere, outward wound."""
    m = trimesh.creation.icosphere(subdivisions=int(subdivisions), radius=float(radius))
    return np.asarray(m.vertices, dtype=np.float64) + np.asarray(center, dtype=np.float64), \
        np.asarray(m.faces, dtype=np.int64)


def moving_sphere_keyframes(radius: float, subdivisions: int, centers) -> tuple[np.ndarray, np.ndarray]:
    """Keyframes (K, V, 3) of an icosphere whose centre passes through `centers` (K, 3), and its faces."""
    x0, faces = icosphere(radius, subdivisions)
    centers = np.asarray(centers, dtype=np.float64).reshape(-1, 3)
    return x0[None] + centers[:, None, :], faces


class SkinnedMannequin:
    """Vertex positions of the mannequin's body as a triangle mesh: each capsule tessellated in
    its joint's frame (`capsule_tessellation`), so every vertex follows its capsule rigidly.
    Callable: t -> (V, 3) world positions, placed as the Mannequin is (position, heading, phase)."""

    def __init__(self, mannequin, segments: int = 12):
        self.motion = mannequin.motion
        self.offset = np.asarray(mannequin.offset, dtype=np.float64)
        self.heading = float(mannequin.place_heading)
        self.phase = float(mannequin.phase)
        local, joint, faces, n = [], [], [], 0
        for joint_name, a, b, r in CAPSULES.values():
            v, f = capsule_tessellation(a, b, r, segments)
            local.append(v)
            joint.append(np.full(len(v), JOINTS.index(joint_name)))
            faces.append(f + n)
            n += len(v)
        self.local = np.vstack(local)  # (V, 3) m, in the frame of the vertex's joint
        self.vert_joint = np.concatenate(joint)  # (V,) index into character.JOINTS
        self.faces = np.vstack(faces)

    def __call__(self, t: float) -> np.ndarray:
        R, p = joint_frames(self.motion.pose(motion_time(t, self.phase)))
        R, p = R[self.vert_joint], p[self.vert_joint]
        x = np.einsum("vij,vj->vi", R, self.local) + p
        c, s = np.cos(self.heading), np.sin(self.heading)
        place = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return x @ place.T + self.offset


def skinned_mannequin_mesh(mannequin, segments: int = 12, name: str = "mannequin_mesh",
                           query_radius: float | None = None) -> TriangleMeshObstacle:
    """The mannequin's body (a cloth.character.Mannequin) as a moving triangle mesh: one closed
    tessellated capsule per body capsule, moving with its joint; the union of the capsules, as
    the capsule body is, up to the tessellation (facets inside by about r (1 - cos(pi/segments)))."""
    skin = SkinnedMannequin(mannequin, segments)
    return TriangleMeshObstacle(skin, skin.faces, name=name, query_radius=query_radius)
