"""Procedural garments in material space, put on the mannequin through pinned nodes.

A garment's material coordinates are its flat pattern (metres) and its world positions start
isometric to the pattern (no initial strain) and clear of the body; the nodes of its waistband
or collar are pinned to a joint of the mannequin (a :class:`cloth.core.scene.Handle` whose motion is
that joint's, :class:`JointMotion`).

* `circle_skirt`: an annulus (inner radius = waist, width = length) that starts as a flat disc
  around the waist, falls and drapes. No seam. Meshed with near-uniform edges
  (`uniform_annulus_mesh`: more nodes on the longer rings further out).
* `tube_skirt`: a rectangle of width 2 pi r rolled into a vertical tube around the hips, its
  two side edges joined by a seam (every seam node has two verts), pinned at the waist.
  Two of them, one over the other, make the layered outfit of the karate scene.
* `obj_garment`: a garment of the user's, read from an OBJ file with texture coordinates
  (`cloth.io.obj.load_obj`: positions become nodes, UVs material coordinates, a position with
  several UVs a seam node), placed with the body and pinned by default along its boundary loop
  nearest to the attachment joint (a skirt's waistband, a shirt's collar).

Garments of one character are merged into one Mesh (`merge_garments`); the connected components
do not interact with each other until self-collision lands (see the karate scene's notes).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from cloth.core.mesh import Mesh, MeshError, grid_mesh, merge_meshes
from cloth.io.obj import ObjError, load_obj
from cloth.scenes.character import JOINTS, Mannequin, forward_kinematics


def _heading(angle: float) -> np.ndarray:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


@dataclass
class JointMotion:
    """The rigid motion of one joint of a placed mannequin, as a handle motion: pose(t) -> (R, p)."""

    body: Mannequin
    joint: str

    def pose(self, t: float):
        R, p = self.body.frames_at(t)[self.joint]
        Rh = _heading(self.body.place_heading)
        return Rh @ R, Rh @ p + self.body.offset


@dataclass
class Garment:
    """A garment on a body: its mesh, the nodes pinned to the body and the joint they follow."""

    name: str
    mesh: Mesh
    pinned: np.ndarray  # (k,) node indices of the waistband / collar
    motion: JointMotion


def _joint_center(body: Mannequin, joint: str, height: float) -> np.ndarray:
    """World position of `joint` at t = 0, raised by `height` metres."""
    _, p = forward_kinematics(body.pose_at(0.0))[joint]
    return _heading(body.place_heading) @ p + body.offset + np.array([0.0, 0.0, height])


def annulus_mesh(inner_radius: float, width: float, n_around: int, n_across: int,
                 center=(0.0, 0.0, 0.0)) -> Mesh:
    """A flat annulus in the plane z = center[2]: material coordinates (r cos t, r sin t), world
    positions the same around `center`. Node i * n_around + j is on ring i (radius
    inner_radius + i width / n_across) at angle 2 pi j / n_around; the ring closes on itself.
    """
    if inner_radius <= 0 or width <= 0:
        raise MeshError(f"annulus radii must be > 0 m, got inner {inner_radius}, width {width}")
    if n_around < 3 or n_across < 1:
        raise MeshError(f"annulus needs >= 3 segments around and >= 1 across, got {n_around}, {n_across}")
    r = inner_radius + width * np.arange(n_across + 1) / n_across
    t = 2 * np.pi * np.arange(n_around) / n_around
    R, T = np.meshgrid(r, t, indexing="ij")
    u = np.column_stack([(R * np.cos(T)).ravel(), (R * np.sin(T)).ravel()])
    i, j = np.meshgrid(np.arange(n_across), np.arange(n_around), indexing="ij")
    i, j = i.ravel(), j.ravel()
    a, b = i * n_around + j, i * n_around + (j + 1) % n_around
    c, d = a + n_around, b + n_around
    flip = ((i + j) % 2 == 1)[:, None]  # alternate the diagonal: no preferred shear
    fa = np.where(flip, np.column_stack([a, c, b]), np.column_stack([a, d, b]))  # counter-clockwise
    fb = np.where(flip, np.column_stack([b, c, d]), np.column_stack([a, c, d]))
    faces = np.empty((2 * a.size, 3), dtype=np.int32)
    faces[0::2], faces[1::2] = fa, fb
    x = np.column_stack([u, np.zeros(len(u))]) + np.asarray(center, float)
    n = len(u)
    return Mesh(node_x=x, node_v=np.zeros((n, 3)), node_pinned=np.zeros(n, dtype=bool), vert_u=u,
                vert_node=np.arange(n, dtype=np.int32), face_verts=faces)


# Gap between the rings of `uniform_annulus_mesh`, in units of its edge length: 3 / pi, so that
# each ring is 2 pi x gap = 6 edges longer than the one inside it (about 6 more nodes, as in the
# rings of a hexagonal disc). Not the equilateral sqrt(3) / 2: rings with different node counts
# line up somewhere, and there the strip between them has a right triangle with legs the gap and
# a segment, whose hypotenuse over its shorter leg is sqrt(1 + (edge / gap)^2): 1.53 with the
# equilateral gap, 1.45 with this one. Where the rings are staggered the triangles have edges
# 1, 1.08, 1.08 x edge: near-equilateral.
RING_GAP = 3.0 / np.pi


def _ring_strip(n_in: int, n_out: int, first_in: int, first_out: int) -> np.ndarray:
    """(n_in + n_out, 3) faces, counter-clockwise seen from +z, of the strip between an inner ring
    of n_in nodes (first_in + k at angle 2 pi k / n_in) and a larger outer ring of n_out nodes
    (first_out + k at angle 2 pi k / n_out). One face per segment of either ring, the segments
    taken in the order of their mid-angles: a face on an inner segment has its apex at the
    current outer node, one on an outer segment at the current inner node. This walk always
    takes the quad's shorter diagonal (by angle) and keeps the two rings in step; it starts and
    ends at the edge between the nodes at angle 0."""
    mid = np.concatenate([(np.arange(n_in) + 0.5) / n_in, (np.arange(n_out) + 0.5) / n_out])  # turns
    outer = np.concatenate([np.zeros(n_in, dtype=bool), np.ones(n_out, dtype=bool)])[np.argsort(mid, kind="stable")]
    j = (np.cumsum(~outer) - ~outer) % n_in  # the current inner node: inner segments done so far
    k = (np.cumsum(outer) - outer) % n_out
    a, a_next = first_in + j, first_in + (j + 1) % n_in
    b, b_next = first_out + k, first_out + (k + 1) % n_out
    return np.where(outer[:, None], np.column_stack([a, b, b_next]), np.column_stack([a, b, a_next]))


def uniform_annulus_mesh(inner_radius: float, width: float, edge: float, center=(0.0, 0.0, 0.0),
                         cell_aspect: float = 1.0) -> Mesh:
    """A flat annulus in the plane z = center[2] whose edges are all about `edge` metres long:
    material coordinates (r cos t, r sin t), world positions the same around `center`.

    Rings of nodes at radii inner_radius + i width / n_rings, i = 0 .. n_rings, the gap between
    them (RING_GAP x edge x cell_aspect; rounded so that the last ring is the outer edge) and
    their nodes round(2 pi r / edge) (at least 3) at angles 2 pi k / n. Nodes are numbered ring by
    ring from the inner one, so nodes 0 .. n_0 - 1 are the inner ring's, in order from angle 0.
    Consecutive rings are joined by `_ring_strip`. With cell_aspect = 1 and a few rings (width of
    several edges), the longest edge over the shortest is below 1.5 and the smallest angle above
    40 degrees; cell_aspect > 1 makes the rings that many times further apart (thin triangles,
    long across and short around).
    """
    if inner_radius <= 0 or width <= 0:
        raise MeshError(f"annulus radii must be > 0 m, got inner {inner_radius}, width {width}")
    if not edge > 0:
        raise MeshError(f"annulus edge length must be > 0 m, got {edge}")
    if not cell_aspect > 0:
        raise MeshError(f"annulus cell_aspect must be > 0, got {cell_aspect}")
    n_rings = max(1, int(round(width / (RING_GAP * edge * cell_aspect))))
    r = inner_radius + width * np.arange(n_rings + 1) / n_rings
    n = np.maximum(3, np.round(2 * np.pi * r / edge).astype(np.int64))
    first = np.concatenate([[0], np.cumsum(n)])
    ring = np.repeat(np.arange(n_rings + 1), n)
    t = 2 * np.pi * (np.arange(first[-1]) - first[ring]) / n[ring]
    u = np.column_stack([r[ring] * np.cos(t), r[ring] * np.sin(t)])
    faces = np.concatenate([_ring_strip(n[i], n[i + 1], first[i], first[i + 1]) for i in range(n_rings)])
    x = np.column_stack([u, np.zeros(len(u))]) + np.asarray(center, float)
    m = len(u)
    return Mesh(node_x=x, node_v=np.zeros((m, 3)), node_pinned=np.zeros(m, dtype=bool), vert_u=u,
                vert_node=np.arange(m, dtype=np.int32), face_verts=faces.astype(np.int32))


def tube_mesh(radius: float, length: float, n_around: int, n_along: int, top_center=(0.0, 0.0, 0.0),
              seam_angle: float = -np.pi / 2) -> Mesh:
    """A vertical tube of `radius` hanging `length` below `top_center`, rolled from a flat
    rectangle of 2 pi radius x length with a seam: the rectangle's two side edges (u = 0 and
    u = 2 pi radius) have their own verts but share nodes. The seam is at `seam_angle` (rad about z;
    the default -pi/2 is the back of a character facing +y). Nodes j * n_around + i are on row j
    (j = 0 the hem, j = n_along the top) at angle seam_angle + 2 pi i / n_around.
    """
    if radius <= 0 or length <= 0:
        raise MeshError(f"tube radius and length must be > 0 m, got {radius}, {length}")
    if n_around < 3 or n_along < 1:
        raise MeshError(f"tube needs >= 3 segments around and >= 1 along, got {n_around}, {n_along}")
    flat = grid_mesh(2 * np.pi * radius, length, n_around, n_along)
    i, j = np.divmod(np.arange(flat.n_verts), n_around + 1)[::-1]  # vert = j (n_around + 1) + i
    vert_node = (j * n_around + i % n_around).astype(np.int32)
    n = (n_along + 1) * n_around
    angle = seam_angle + flat.vert_u[:, 0] / radius
    x = np.empty((n, 3))
    x[vert_node] = np.column_stack([radius * np.cos(angle), radius * np.sin(angle),
                                    flat.vert_u[:, 1] - length]) + np.asarray(top_center, float)
    return Mesh(node_x=x, node_v=np.zeros((n, 3)), node_pinned=np.zeros(n, dtype=bool), vert_u=flat.vert_u,
                vert_node=vert_node, face_verts=flat.face_verts)


def _segments_across(length: float, circumference: float, n_around: int) -> int:
    """Segments along a garment's length that keep its faces near-equilateral."""
    return max(1, int(round(length / (circumference / n_around))))


def circle_skirt(body: Mannequin, *, waist_radius: float = 0.18, length: float = 0.55, resolution: int = 48,
                 waist_joint: str = "abdomen", waist_height: float = 0.06, cell_aspect: float = 1.0) -> Garment:
    """A circle skirt around `body`'s waist: a flat disc (annulus) at the waist at t = 0.

    `resolution` segments around the waist, which sets the edge length 2 pi waist_radius /
    resolution of the whole skirt: the rings further out have more nodes (`uniform_annulus_mesh`),
    so the edges are near-uniform (the longest over the shortest below 1.5 when the skirt is
    several edges long) and the faces near-equilateral. With `cell_aspect` > 1 the rings are that
    many times further apart, making cells that many times longer across than around (thin
    input triangles, the stability suite's thin garment). The waistband ring (nodes 0 ..
    resolution - 1) sits `waist_height` above the `waist_joint` and is pinned to it.
    """
    if not cell_aspect >= 1:
        raise MeshError(f"circle skirt cell_aspect must be >= 1, got {cell_aspect}")
    n_around = int(resolution)
    if n_around < 3:
        raise MeshError(f"circle skirt needs >= 3 segments around the waist, got {resolution}")
    mesh = uniform_annulus_mesh(waist_radius, length, 2 * np.pi * waist_radius / n_around,
                                _joint_center(body, waist_joint, waist_height), cell_aspect=cell_aspect)
    return Garment("circle_skirt", mesh, np.arange(n_around), JointMotion(body, waist_joint))


def tube_skirt(body: Mannequin, *, waist_radius: float = 0.26, length: float = 0.55, resolution: int = 48,
               waist_joint: str = "pelvis", waist_height: float = 0.06) -> Garment:
    """A straight wide skirt (a tube with a seam at the back, like a hakama) hanging from a
    waistband pinned `waist_height` above the `waist_joint`. Its radius must clear the hips
    (0.19 m from the body's axis); a body whose arms hang at its sides has its hands inside such a
    tube, so the motion must hold the arms up (the karate motion's opening pose does)."""
    n_around = int(resolution)
    n_along = _segments_across(length, 2 * np.pi * waist_radius, n_around)
    mesh = tube_mesh(waist_radius, length, n_around, n_along, _joint_center(body, waist_joint, waist_height),
                     seam_angle=body.place_heading - np.pi / 2)
    return Garment("tube_skirt", mesh, n_along * n_around + np.arange(n_around), JointMotion(body, waist_joint))


def boundary_loops(mesh: Mesh) -> list[np.ndarray]:
    """The mesh's boundary loops: node indices of each connected chain of boundary edges (node
    edges with one face; seams are not boundary), in order of their smallest node."""
    edges = mesh.edge_nodes[mesh.edge_faces[:, 1] < 0]
    if len(edges) == 0:
        return []
    n = mesh.n_nodes
    graph = coo_matrix((np.ones(len(edges)), (edges[:, 0], edges[:, 1])), shape=(n, n))
    _, label = connected_components(graph, directed=False)
    nodes = np.unique(edges)
    return [nodes[label[nodes] == c] for c in np.unique(label[nodes])]


def pins_near_joint(mesh: Mesh, joint_position, pin_distance: float = 0.0) -> np.ndarray:
    """Default pinned nodes of a garment: its boundary loop nearest to `joint_position` (m; the
    loop whose nodes are closest to it on average, so a waistband wins over a hem that passes
    near the joint at one point), plus every node within `pin_distance` metres of that loop."""
    loops = boundary_loops(mesh)
    if not loops:
        raise MeshError("has no boundary loop to pin to the body (a closed surface)")
    p = np.asarray(joint_position, dtype=np.float64)
    loop = min(loops, key=lambda nodes: float(np.linalg.norm(mesh.node_x[nodes] - p, axis=1).mean()))
    if pin_distance > 0:
        d, _ = cKDTree(mesh.node_x[loop]).query(mesh.node_x)
        loop = np.union1d(loop, np.flatnonzero(d <= pin_distance))
    return np.sort(loop).astype(np.int64)


def obj_garment(body: Mannequin, path, *, scale: float = 1.0, offset=(0.0, 0.0, 0.0), uv_scale: float = 1.0,
                joint: str = "abdomen", pin_distance: float = 0.0) -> Garment:
    """A garment read from the OBJ file `path` and pinned to `body`'s `joint`.

    Positions: OBJ positions x `scale` + `offset` (m), in the frame of the body's placement (the
    world frame for a body at the origin facing +y; a placed or turned body carries the garment
    with it), and they are the garment's positions at t = 0, dressed on the body's opening pose.
    Material coordinates: texture coordinates x `uv_scale` (metres per UV unit); one position
    with several texture coordinates is a seam node (see cloth.io.obj). Pinned: the boundary loop
    nearest to the joint at t = 0, plus the nodes within `pin_distance` m of it (pins_near_joint).
    Raises MeshError (cloth.io.obj.ObjError) whose message starts with the file's path.
    """
    path = Path(path).expanduser()
    if joint not in JOINTS:
        raise MeshError(f"unknown joint {joint!r}; known: {list(JOINTS)}")
    if not scale > 0:
        raise MeshError(f"scale must be > 0, got {scale}")
    if not pin_distance >= 0:
        raise MeshError(f"pin_distance must be >= 0 m, got {pin_distance}")
    offset = np.asarray(offset, dtype=np.float64)
    if offset.shape != (3,):
        raise MeshError(f"offset must be three numbers (m), got {offset.tolist()!r}")
    mesh = load_obj(path, uv_scale=uv_scale, position_scale=scale)
    mesh.node_x[:] = (mesh.node_x + offset) @ _heading(body.place_heading).T + body.offset
    try:
        pinned = pins_near_joint(mesh, _joint_center(body, joint, 0.0), pin_distance)
    except MeshError as exc:
        raise ObjError(f"{path}: {exc}") from None
    body.set_time(0.0)
    phi, _, _ = body.query(mesh.node_x)
    if phi.min() < 0:  # contact keeps cloth out of the body; it cannot start inside it
        raise ObjError(f"{path}: {np.count_nonzero(phi < 0)} of {mesh.n_nodes} nodes start inside the body "
                       f"(deepest {-phi.min():.3f} m) in its opening pose; move the garment (offset, scale)")
    return Garment("obj_garment", mesh, pinned, JointMotion(body, joint))


GARMENTS = {"circle_skirt": circle_skirt, "tube_skirt": tube_skirt, "obj": obj_garment}


def merge_garments(garments: list[Garment]) -> tuple[Mesh, list[np.ndarray]]:
    """One Mesh holding every garment (disjoint components), and each garment's pinned nodes in it."""
    if not garments:
        raise MeshError("a character needs at least one garment")
    mesh = merge_meshes([g.mesh for g in garments])
    mesh.node_pinned[:] = False
    offsets = np.cumsum([0] + [g.mesh.n_nodes for g in garments])[:-1]
    pins = [np.asarray(g.pinned) + o for g, o in zip(garments, offsets)]
    return mesh, pins
