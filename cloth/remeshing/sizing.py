"""The physics sizing field of adaptive remeshing (Narain, Samii and O'Brien 2012, section 4).

A sizing tensor M is a symmetric 2x2 metric in material space (1/m^2): an edge u is the right
length when u^T M u = 1. One function per refinement criterion, each returning (F, 2, 2):

* :func:`curvature_sizing`   bending of the surface (shape operator and normal derivative), 1/refine_angle^2
* :func:`velocity_sizing`    variation of velocity across the face, 1/refine_velocity^2
* :func:`compression_sizing` resolution needed to represent buckling under compression (refine_compression)
* :func:`obstacle_sizing`    nearness of an obstacle along its normal

:func:`combine_sizing` takes their tensor maximum (or sum), clamps eigenvalues to
[size_max^-2, size_min^-2] and bounds anisotropy by aspect_min; :func:`face_to_vert_sizing`
averages faces to verts by area. :func:`physics_face_sizing` is the whole view-independent
field; the view-dependent mode scales its result (eq 2) and nothing else differs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from cloth.core.mesh import Mesh
from cloth.core.tensors import eig2x2, eig_apply
from cloth.physics.membrane import face_green_strain


@dataclass(frozen=True)
class SizingParams:
    refine_angle: float = 0.3  # rad: largest dihedral bend per edge
    refine_velocity: float = 0.5  # (m/s)/(m/s) = 1: largest relative velocity change per edge
    refine_compression: float = 0.005  # largest compression (1 - stretch) per edge left unresolved
    size_min: float = 0.01  # m: shortest edge the field asks for
    size_max: float = 0.2  # m: longest edge the field allows
    aspect_min: float = 0.2  # smallest ratio of the sizing's short to long edge length
    obstacle_distance: float = 0.01  # m: obstacles nearer than this refine the cloth (ARCSim: 10 x 1 mm)
    combine: str = "max"  # "max" (tensor maximum, ARCSim's default) or "sum"

    def __post_init__(self):
        for key in ("refine_angle", "refine_velocity", "refine_compression", "size_min", "size_max",
                    "aspect_min"):
            if not getattr(self, key) > 0:
                raise ValueError(f"{key} must be > 0, got {getattr(self, key)}")
        if not self.size_min <= self.size_max:
            raise ValueError(f"size_min ({self.size_min}) must be <= size_max ({self.size_max})")
        if not self.aspect_min <= 1:
            raise ValueError(f"aspect_min must be <= 1, got {self.aspect_min}")
        if self.obstacle_distance < 0:
            raise ValueError(f"obstacle_distance must be >= 0, got {self.obstacle_distance}")
        if self.combine not in ("max", "sum"):
            raise ValueError(f"combine must be 'max' or 'sum', got {self.combine!r}")


# ---------------------------------------------------------------------------------------
# small tensor helpers
def _gradient_material(values: np.ndarray, face_nodes: np.ndarray, Dm_inv: np.ndarray) -> np.ndarray:
    """Material-space gradient of a per-node field linear on each face: (F, d, 2) = [q1-q0, q2-q0] Dm^-1."""
    q = values[face_nodes]  # (F, 3, d)
    D = np.stack([q[:, 1] - q[:, 0], q[:, 2] - q[:, 0]], axis=2)  # (F, d, 2)
    return D @ Dm_inv


def _gram(A: np.ndarray) -> np.ndarray:
    """A^T A for a stack of (d, 2) matrices."""
    return np.einsum("fki,fkj->fij", A, A)


def node_normals(mesh: Mesh) -> np.ndarray:
    """(n_nodes, 3) area-weighted unit normals of the world surface."""
    x = mesh.node_x[mesh.face_nodes]
    n = np.cross(x[:, 1] - x[:, 0], x[:, 2] - x[:, 0])  # 2 * area * unit normal
    out = np.zeros((mesh.n_nodes, 3))
    for k in range(3):
        np.add.at(out, mesh.face_nodes[:, k], n)
    ln = np.linalg.norm(out, axis=1, keepdims=True)
    return out / np.where(ln > 0, ln, 1.0)


def dihedral_angles(mesh: Mesh) -> np.ndarray:
    """(n_edges,) unsigned angle between the normals of each interior edge's faces (0 on the boundary)."""
    fn = mesh.world_face_normals()
    ef = mesh.edge_faces
    theta = np.zeros(mesh.n_edges)
    inner = ef[:, 1] >= 0
    c = np.einsum("ij,ij->i", fn[ef[inner, 0]], fn[ef[inner, 1]])
    theta[inner] = np.arccos(np.clip(c, -1.0, 1.0))
    return theta


# ---------------------------------------------------------------------------------------
# criteria
def curvature_sizing(mesh: Mesh, refine_angle: float) -> np.ndarray:
    """M_curv = max(S^T S, N^T N) / refine_angle^2.

    S is the discrete shape operator of the face in material coordinates,
    S = (1/A) sum_e (theta_e l_e / 2) t_e t_e^T over its edges (theta_e the dihedral angle,
    l_e the rest length, t_e the in-plane unit normal of the edge), and N (3x2) the
    material-space derivative of the node normals. An edge of length l across which the
    surface turns by about l*|S| then has size l*|S|/refine_angle.
    """
    theta = dihedral_angles(mesh)
    u = mesh.vert_u[mesh.face_verts]  # (F, 3, 2)
    S = np.zeros((mesh.n_faces, 2, 2))
    for k in range(3):
        e = u[:, (k + 1) % 3] - u[:, k]
        length = np.linalg.norm(e, axis=1)
        t = np.column_stack([e[:, 1], -e[:, 0]]) / length[:, None]  # in-plane normal of side k
        w = 0.5 * theta[mesh.face_edges[:, k]] * length / mesh.face_area
        S += w[:, None, None] * t[:, :, None] * t[:, None, :]
    N = _gradient_material(node_normals(mesh), mesh.face_nodes, mesh.face_Dm_inv)
    return tensor_max(np.stack([_gram(S), _gram(N)])) / refine_angle**2


def velocity_sizing(mesh: Mesh, refine_velocity: float) -> np.ndarray:
    """M_vel = V^T V / refine_velocity^2, V (3x2) the material-space gradient of velocity (1/s).

    Velocity gradients are made dimensionless as ARCSim does, per unit of the gradient in 1/s.
    """
    V = _gradient_material(mesh.node_v, mesh.face_nodes, mesh.face_Dm_inv)
    return _gram(V) / refine_velocity**2


def compression_sizing(mesh: Mesh, refine_compression: float, E: np.ndarray | None = None) -> np.ndarray:
    """Resolution needed to represent buckling under compression (ARCSim's compression metric).

    With e = F^T F - I = 2E (E the Green strain, eq 9), the normal-derivative metric
    S2 = N^T N and c = refine_compression,

        M_comp = pos(-e + sqrt(e^T e - 4 c^2 adj(S2))) / (2 c^2),

    where sqrt acts on eigenvalues (keeping their sign) and pos keeps the non-negative ones.
    For a flat face compressed along one direction (e = diag(-eps, 0), S2 = 0) it is
    diag(eps / c^2, 0): edges of length c / sqrt(eps) along the compression, so that the
    compression the mesh cannot show as buckles stays below c per edge; the curvature the mesh
    already resolves (S2) lowers the demand. Stretched directions ask for nothing.
    """
    if E is None:
        E = face_green_strain(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv)
    e = 2.0 * E
    N = _gradient_material(node_normals(mesh), mesh.face_nodes, mesh.face_Dm_inv)
    S2 = _gram(N)
    adj = np.empty_like(S2)
    adj[:, 0, 0], adj[:, 1, 1] = S2[:, 1, 1], S2[:, 0, 0]
    adj[:, 0, 1], adj[:, 1, 0] = -S2[:, 1, 0], -S2[:, 0, 1]
    c2 = refine_compression**2
    D = np.einsum("fki,fkj->fij", e, e) - 4.0 * c2 * adj
    root = eig_apply(D, lambda w: np.sign(w) * np.sqrt(np.abs(w)))
    return eig_apply(-e + root, lambda w: np.maximum(w, 0.0)) / (2.0 * c2)


def obstacle_sizing(mesh: Mesh, phi: np.ndarray, normal: np.ndarray, distance: float) -> np.ndarray:
    """M_obs: for each corner i of a face with an obstacle within `distance`, the height of the
    face's nodes above the obstacle's tangent plane at node i, h_j = (x_j - x_i).n_i + phi_i, has
    material gradient g; M_obs = mean over corners of g g^T / h_i^2. A face tilted towards a
    near obstacle is refined so its nodes sample the gap.

    `phi` (n_nodes,) distance of each node to the nearest obstacle surface, `normal` (n_nodes, 3)
    its outward unit normal there.
    """
    F = mesh.n_faces
    out = np.zeros((F, 2, 2))
    near = phi < distance
    if not np.any(near):
        return out
    fn = mesh.face_nodes
    x = mesh.node_x[fn]  # (F, 3, 3)
    for i in range(3):
        ni = fn[:, i]
        use = near[ni] & (phi[ni] > 0)
        if not np.any(use):
            continue
        h = np.einsum("fjk,fk->fj", x - x[:, i:i + 1], normal[ni]) + phi[ni][:, None]  # (F, 3)
        dh = np.stack([h[:, 1] - h[:, 0], h[:, 2] - h[:, 0]], axis=1)  # (F, 2)
        g = np.einsum("fk,fkj->fj", dh, mesh.face_Dm_inv)
        term = g[:, :, None] * g[:, None, :] / np.maximum(phi[ni], 1e-12)[:, None, None] ** 2
        out[use] += term[use]
    return out / 3.0


# ---------------------------------------------------------------------------------------
# tensor maximum: smallest enclosing disk of the tensors' disks
@nb.njit(cache=True)
def _encloses(cx, cy, r, dx, dy, dr):
    return math.sqrt((cx - dx) ** 2 + (cy - dy) ** 2) + dr <= r * (1.0 + 1e-9) + 1e-12


@nb.njit(cache=True)
def _encloses_all(px, py, r, cx, cy, rr, K):
    for k in range(K):
        if not _encloses(px, py, r, cx[k], cy[k], rr[k]):
            return False
    return True


@nb.njit(cache=True)
def _tensor_max_one(Ms, out):
    """The smallest-trace symmetric M with M >= M_k for all k (Loewner order), M_k 2x2 symmetric.

    Writing M = r I + [[c0, c1], [c1, -c0]], M >= M_k iff the disk (c, r) contains the disk
    (c_k, r_k); the answer is the smallest disk enclosing all of them (candidates through one,
    two or three tangent disks; K is small).
    """
    K = Ms.shape[0]
    _tensor_max_into(Ms, out, np.empty(K), np.empty(K), np.empty(K), np.empty(2))


@nb.njit(cache=True)
def _tensor_max_into(Ms, out, cx, cy, rr, roots):
    """_tensor_max_one with its scratch arrays given (cx, cy, rr of length K, roots of 2)."""
    K = Ms.shape[0]
    for k in range(K):
        cx[k] = 0.5 * (Ms[k, 0, 0] - Ms[k, 1, 1])
        cy[k] = 0.5 * (Ms[k, 0, 1] + Ms[k, 1, 0])
        rr[k] = 0.5 * (Ms[k, 0, 0] + Ms[k, 1, 1])
    best_r, bx, by = _disk_max(cx, cy, rr, K, roots)
    out[0, 0] = best_r + bx
    out[1, 1] = best_r - bx
    out[0, 1] = by
    out[1, 0] = by


@nb.njit(cache=True)
def _disk_max(cx, cy, rr, K, roots):
    """The smallest disk (radius, centre x, centre y) enclosing the first K disks (cx, cy, rr)."""
    best_r = np.inf
    bx = 0.0
    by = 0.0
    # Any enclosing disk contains each disk, and the smallest one is unique: so a disk of the set
    # that encloses all is the answer, and so is the first two-disk candidate that encloses all
    # (the smallest disk enclosing those two); only then are three-disk candidates needed.
    for i in range(K):  # one disk
        if _encloses_all(cx[i], cy[i], rr[i], cx, cy, rr, K):
            return rr[i], cx[i], cy[i]
    for i in range(K):  # two disks tangent inside
        for j in range(i + 1, K):
            d = math.sqrt((cx[j] - cx[i]) ** 2 + (cy[j] - cy[i]) ** 2)
            if d == 0.0:
                continue
            r = 0.5 * (rr[i] + d + rr[j])
            t = (r - rr[i]) / d
            px = cx[i] + t * (cx[j] - cx[i])
            py = cy[i] + t * (cy[j] - cy[i])
            if r < best_r and _encloses_all(px, py, r, cx, cy, rr, K):
                best_r, bx, by = r, px, py
    if best_r < np.inf:
        return best_r, bx, by
    for i in range(K):  # three disks tangent inside: |c - c_k| = R - r_k
        for j in range(i + 1, K):
            for l in range(j + 1, K):
                # 2 (c_k - c_i).c - 2 (r_k - r_i) R = |c_k|^2 - |c_i|^2 - r_k^2 + r_i^2, k = j, l
                a11, a12 = 2 * (cx[j] - cx[i]), 2 * (cy[j] - cy[i])
                a21, a22 = 2 * (cx[l] - cx[i]), 2 * (cy[l] - cy[i])
                det = a11 * a22 - a12 * a21
                if abs(det) < 1e-14 * (abs(a11 * a22) + abs(a12 * a21) + 1e-300):
                    continue
                b1 = cx[j] ** 2 + cy[j] ** 2 - cx[i] ** 2 - cy[i] ** 2 - rr[j] ** 2 + rr[i] ** 2
                b2 = cx[l] ** 2 + cy[l] ** 2 - cx[i] ** 2 - cy[i] ** 2 - rr[l] ** 2 + rr[i] ** 2
                g1, g2 = 2 * (rr[j] - rr[i]), 2 * (rr[l] - rr[i])
                # c = P + Q R
                Px = (b1 * a22 - a12 * b2) / det
                Py = (a11 * b2 - b1 * a21) / det
                Qx = (g1 * a22 - a12 * g2) / det
                Qy = (a11 * g2 - g1 * a21) / det
                # |P + Q R - c_i|^2 = (R - r_i)^2
                ux, uy = Px - cx[i], Py - cy[i]
                qa = Qx * Qx + Qy * Qy - 1.0
                qb = 2.0 * (ux * Qx + uy * Qy) + 2.0 * rr[i]
                qc = ux * ux + uy * uy - rr[i] ** 2
                nr = 0
                if abs(qa) < 1e-14:
                    if qb != 0.0:
                        roots[0] = -qc / qb
                        nr = 1
                else:
                    disc = qb * qb - 4 * qa * qc
                    if disc < 0:
                        continue
                    sd = math.sqrt(disc)
                    roots[0] = (-qb - sd) / (2 * qa)
                    roots[1] = (-qb + sd) / (2 * qa)
                    nr = 2
                for m in range(nr):
                    R = roots[m]
                    if R < max(rr[i], rr[j], rr[l]) or R >= best_r:
                        continue
                    px, py = Px + Qx * R, Py + Qy * R
                    if _encloses_all(px, py, R, cx, cy, rr, K):
                        best_r, bx, by = R, px, py
    return best_r, bx, by


@nb.njit(cache=True)
def _tensor_max_faces(Ms, out):
    K, F = Ms.shape[0], Ms.shape[1]
    buf = np.empty((K, 2, 2))
    for f in range(F):
        for k in range(K):
            buf[k] = Ms[k, f]
        _tensor_max_one(buf, out[f])


def tensor_max(Ms: np.ndarray) -> np.ndarray:
    """Tensor maximum over axis 0 of (K, F, 2, 2) symmetric tensors: (F, 2, 2).

    The result M satisfies u^T M u >= u^T M_k u for every k and direction u, with the
    smallest trace; it equals M_k when M_k dominates all others.
    """
    Ms = np.ascontiguousarray(Ms, dtype=np.float64)
    out = np.empty(Ms.shape[1:])
    _tensor_max_faces(Ms, out)
    return out


def clamp_sizing(M: np.ndarray, size_min: float, size_max: float, aspect_min: float) -> np.ndarray:
    """Eigenvalues clamped to [size_max^-2, size_min^-2], then the smaller raised to at least
    aspect_min^2 times the larger (edges at most 1/aspect_min times longer one way than the other)."""
    def fn(w):
        w = np.clip(w, 1.0 / size_max**2, 1.0 / size_min**2)
        lo = aspect_min**2 * w.max(axis=1, keepdims=True)
        return np.maximum(w, lo)
    return eig_apply(0.5 * (M + np.swapaxes(M, 1, 2)), fn)


def combine_sizing(Ms: list[np.ndarray], params: SizingParams) -> np.ndarray:
    """Combine criteria (tensor max or sum), then clamp (:func:`clamp_sizing`)."""
    stack = np.stack(Ms)
    M = tensor_max(stack) if params.combine == "max" else stack.sum(axis=0)
    return clamp_sizing(M, params.size_min, params.size_max, params.aspect_min)


def physics_face_sizing_reference(mesh: Mesh, params: SizingParams, obstacles=None) -> np.ndarray:
    """:func:`physics_face_sizing` criterion by criterion, with the functions above (the
    definition the fused kernel is tested against)."""
    Ms = [curvature_sizing(mesh, params.refine_angle),
          velocity_sizing(mesh, params.refine_velocity),
          compression_sizing(mesh, params.refine_compression)]
    if obstacles is not None and params.obstacle_distance > 0:
        phi, normal, _ = obstacles.query(mesh.node_x)
        Ms.append(obstacle_sizing(mesh, phi, normal, params.obstacle_distance))
    return combine_sizing(Ms, params)


def physics_face_sizing(mesh: Mesh, params: SizingParams, obstacles=None) -> np.ndarray:
    """The view-independent sizing field of ARCSim, per face (F, 2, 2) in 1/m^2.

    `obstacles` is a cloth.collision.obstacles.ObstacleSet placed at the current time, or None.
    The criteria, their tensor maximum (or sum) and the clamp of :func:`combine_sizing`, fused
    in one pass over the faces (:func:`_physics_sizing_faces`); the same field as
    :func:`physics_face_sizing_reference` to round-off.
    """
    fn = np.ascontiguousarray(mesh.face_nodes, dtype=np.int64)
    x = np.ascontiguousarray(mesh.node_x, dtype=np.float64)
    with_obstacles = obstacles is not None and params.obstacle_distance > 0
    if with_obstacles:
        phi, normal, _ = obstacles.query(mesh.node_x)
        phi = np.ascontiguousarray(phi, dtype=np.float64)
        normal = np.ascontiguousarray(normal, dtype=np.float64)
    else:
        phi, normal = np.empty(0), np.empty((0, 3))
    face_n, node_n = _face_and_node_normals(x, fn, mesh.n_nodes)
    theta = _dihedral_from_normals(face_n, np.ascontiguousarray(mesh.edge_faces, dtype=np.int64))
    out = np.empty((mesh.n_faces, 2, 2))
    _physics_sizing_faces(x, np.ascontiguousarray(mesh.node_v, dtype=np.float64), fn,
                          np.ascontiguousarray(mesh.face_verts, dtype=np.int64),
                          np.ascontiguousarray(mesh.face_edges, dtype=np.int64),
                          np.ascontiguousarray(mesh.vert_u, dtype=np.float64), mesh.face_area, mesh.face_Dm_inv,
                          theta, node_n, phi, normal, with_obstacles, float(params.obstacle_distance),
                          float(params.refine_angle), float(params.refine_velocity),
                          float(params.refine_compression), params.combine == "max", float(params.size_min),
                          float(params.size_max), float(params.aspect_min), out)
    return out


@nb.njit(cache=True)
def _face_and_node_normals(x, fn, n_nodes):
    """(unit face normals (F, 3), zero for collapsed faces; area-weighted unit node normals (N, 3))."""
    F = fn.shape[0]
    face_n = np.empty((F, 3))
    acc = np.zeros((n_nodes, 3))
    for f in range(F):
        a, b, c = fn[f, 0], fn[f, 1], fn[f, 2]
        e1x, e1y, e1z = x[b, 0] - x[a, 0], x[b, 1] - x[a, 1], x[b, 2] - x[a, 2]
        e2x, e2y, e2z = x[c, 0] - x[a, 0], x[c, 1] - x[a, 1], x[c, 2] - x[a, 2]
        nx = e1y * e2z - e1z * e2y
        ny = e1z * e2x - e1x * e2z
        nz = e1x * e2y - e1y * e2x
        ln = math.sqrt(nx * nx + ny * ny + nz * nz)
        s = ln if ln > 0.0 else 1.0
        face_n[f, 0], face_n[f, 1], face_n[f, 2] = nx / s, ny / s, nz / s
        for k in range(3):
            i = fn[f, k]
            acc[i, 0] += nx
            acc[i, 1] += ny
            acc[i, 2] += nz
    for i in range(n_nodes):
        ln = math.sqrt(acc[i, 0] ** 2 + acc[i, 1] ** 2 + acc[i, 2] ** 2)
        if ln > 0.0:
            acc[i, 0] /= ln
            acc[i, 1] /= ln
            acc[i, 2] /= ln
    return face_n, acc


@nb.njit(cache=True)
def _dihedral_from_normals(face_n, edge_faces):
    """(E,) unsigned angle between the unit normals of each interior edge's faces (0 on the boundary)."""
    E = edge_faces.shape[0]
    theta = np.zeros(E)
    for e in range(E):
        a, b = edge_faces[e, 0], edge_faces[e, 1]
        if b < 0:
            continue
        c = face_n[a, 0] * face_n[b, 0] + face_n[a, 1] * face_n[b, 1] + face_n[a, 2] * face_n[b, 2]
        theta[e] = math.acos(min(max(c, -1.0), 1.0))
    return theta


@nb.njit(cache=True)
def _set_disk(k, m00, m01, m10, m11, cx, cy, rr):
    """Tensor [[m00, m01], [m10, m11]] as disk k of the tensor maximum (_tensor_max_into)."""
    cx[k] = 0.5 * (m00 - m11)
    cy[k] = 0.5 * (m01 + m10)
    rr[k] = 0.5 * (m00 + m11)


@nb.njit(cache=True)
def _physics_sizing_faces(x, v, fn, fv, fe, u, area, Dm_inv, theta, node_n, phi, obs_n, with_obstacles,
                          obs_distance, refine_angle, refine_velocity, refine_compression, use_max, size_min,
                          size_max, aspect_min, out):
    """Kernel of physics_face_sizing: per face, the curvature, velocity, compression and
    obstacle criteria (each as its function above), combined and clamped (combine_sizing) into out[f]."""
    F = fn.shape[0]
    K = 4 if with_obstacles else 3
    cx, cy, rr, roots = np.empty(K), np.empty(K), np.empty(K), np.empty(2)
    crit = np.zeros((K, 4))  # per criterion m00, m01, m10, m11
    ra2 = refine_angle ** 2
    rv2 = refine_velocity ** 2
    c2 = refine_compression ** 2
    wmin, wmax = 1.0 / size_max ** 2, 1.0 / size_min ** 2
    for f in range(F):
        n0, n1, n2 = fn[f, 0], fn[f, 1], fn[f, 2]
        b00, b01, b10, b11 = Dm_inv[f, 0, 0], Dm_inv[f, 0, 1], Dm_inv[f, 1, 0], Dm_inv[f, 1, 1]
        # curvature: S = sum_k (theta_k l_k / 2A) t_k t_k^T; N (3x2) the gradient of the node normals
        s00 = s01 = s11 = 0.0
        for k in range(3):
            va, vb = fv[f, k], fv[f, (k + 1) % 3]
            ex, ey = u[vb, 0] - u[va, 0], u[vb, 1] - u[va, 1]
            length = math.sqrt(ex * ex + ey * ey)
            tx, ty = ey / length, -ex / length
            w = 0.5 * theta[fe[f, k]] * length / area[f]
            s00 += w * tx * tx
            s01 += w * tx * ty
            s11 += w * ty * ty
        q01 = s00 * s01 + s01 * s11
        _set_disk(0, s00 * s00 + s01 * s01, q01, q01, s01 * s01 + s11 * s11, cx, cy, rr)
        g00 = g01 = g11 = 0.0
        for i in range(3):
            d1, d2 = node_n[n1, i] - node_n[n0, i], node_n[n2, i] - node_n[n0, i]
            a0, a1 = d1 * b00 + d2 * b10, d1 * b01 + d2 * b11
            g00 += a0 * a0
            g01 += a0 * a1
            g11 += a1 * a1
        _set_disk(1, g00, g01, g01, g11, cx, cy, rr)
        r, px, py = _disk_max(cx, cy, rr, 2, roots)
        crit[0, 0], crit[0, 1], crit[0, 2], crit[0, 3] = (r + px) / ra2, py / ra2, py / ra2, (r - px) / ra2
        # velocity: V^T V / refine_velocity^2
        h00 = h01 = h11 = 0.0
        for i in range(3):
            d1, d2 = v[n1, i] - v[n0, i], v[n2, i] - v[n0, i]
            a0, a1 = d1 * b00 + d2 * b10, d1 * b01 + d2 * b11
            h00 += a0 * a0
            h01 += a0 * a1
            h11 += a1 * a1
        crit[1, 0], crit[1, 1], crit[1, 2], crit[1, 3] = h00 / rv2, h01 / rv2, h01 / rv2, h11 / rv2
        # compression: pos(-e + sqrt(e^T e - 4 c^2 adj(N^T N))) / (2 c^2), e = F^T F - I
        h00 = h01 = h11 = 0.0
        for i in range(3):
            d1, d2 = x[n1, i] - x[n0, i], x[n2, i] - x[n0, i]
            a0, a1 = d1 * b00 + d2 * b10, d1 * b01 + d2 * b11
            h00 += a0 * a0
            h01 += a0 * a1
            h11 += a1 * a1
        e00, e01, e11 = 2.0 * (0.5 * (h00 - 1.0)), 2.0 * (0.5 * h01), 2.0 * (0.5 * (h11 - 1.0))
        lo, hi, cs, sn = eig2x2(e00 * e00 + e01 * e01 - 4.0 * c2 * g11, e01 * e00 + e11 * e01 + 4.0 * c2 * g01,
                               e01 * e01 + e11 * e11 - 4.0 * c2 * g00)
        lo = math.copysign(math.sqrt(abs(lo)), lo) if lo != 0.0 else 0.0
        hi = math.copysign(math.sqrt(abs(hi)), hi) if hi != 0.0 else 0.0
        r00, r11, r01 = lo * sn * sn + hi * cs * cs, lo * cs * cs + hi * sn * sn, (hi - lo) * cs * sn
        lo, hi, cs, sn = eig2x2(r00 - e00, r01 - e01, r11 - e11)
        lo, hi = max(lo, 0.0), max(hi, 0.0)
        r01 = (hi - lo) * cs * sn / (2.0 * c2)
        crit[2, 0], crit[2, 1], crit[2, 2] = (lo * sn * sn + hi * cs * cs) / (2.0 * c2), r01, r01
        crit[2, 3] = (lo * cs * cs + hi * sn * sn) / (2.0 * c2)
        # obstacles: the mean over the corners near one of g g^T / phi^2
        if with_obstacles:
            o00 = o01 = o11 = 0.0
            for i in range(3):
                ni = fn[f, i]
                if not (phi[ni] < obs_distance and phi[ni] > 0.0):
                    continue
                h0 = h1 = h2 = 0.0
                for c in range(3):
                    h0 += (x[n0, c] - x[ni, c]) * obs_n[ni, c]
                    h1 += (x[n1, c] - x[ni, c]) * obs_n[ni, c]
                    h2 += (x[n2, c] - x[ni, c]) * obs_n[ni, c]
                h0, h1, h2 = h0 + phi[ni], h1 + phi[ni], h2 + phi[ni]
                dh0, dh1 = h1 - h0, h2 - h0
                a0, a1 = dh0 * b00 + dh1 * b10, dh0 * b01 + dh1 * b11
                p2 = max(phi[ni], 1e-12) ** 2
                o00 += a0 * a0 / p2
                o01 += a0 * a1 / p2
                o11 += a1 * a1 / p2
            crit[3, 0], crit[3, 1], crit[3, 2], crit[3, 3] = o00 / 3.0, o01 / 3.0, o01 / 3.0, o11 / 3.0
        # combine (tensor maximum or sum), then clamp_sizing
        if use_max:
            for k in range(K):
                _set_disk(k, crit[k, 0], crit[k, 1], crit[k, 2], crit[k, 3], cx, cy, rr)
            r, px, py = _disk_max(cx, cy, rr, K, roots)
            m00, m01, m10, m11 = r + px, py, py, r - px
        else:
            m00 = m01 = m10 = m11 = 0.0
            for k in range(K):
                m00 += crit[k, 0]
                m01 += crit[k, 1]
                m10 += crit[k, 2]
                m11 += crit[k, 3]
        lo, hi, cs, sn = eig2x2(m00, 0.5 * (m10 + m01), m11)
        lo, hi = min(max(lo, wmin), wmax), min(max(hi, wmin), wmax)
        floor = aspect_min ** 2 * max(lo, hi)
        lo, hi = max(lo, floor), max(hi, floor)
        out[f, 0, 0] = lo * sn * sn + hi * cs * cs
        out[f, 1, 1] = lo * cs * cs + hi * sn * sn
        out[f, 0, 1] = out[f, 1, 0] = (hi - lo) * cs * sn


# Relative tolerance of "at a bound": clamp_sizing's eigen-decomposition returns the clamped
# eigenvalues to round-off (~1e-15 relative); 1e-9 also absorbs the symmetrisation.
BOUND_RTOL = 1e-9


def sizing_at_bounds(mesh: Mesh, face_M: np.ndarray, size_min: float, size_max: float) -> dict:
    """How much room the sizing field had: per face, whether its finest direction sits at
    size_min (largest eigenvalue of M at 1/size_min^2 or above: the criteria asked for size_min or
    finer) or at size_max (largest eigenvalue at 1/size_max^2 or below: the face is at the coarse
    bound in every direction). Returns faces_sized (the faces of the mesh the field was
    evaluated on, before the remesh), faces_at_size_min, faces_at_size_max and
    edge_at_size_min_m, the median material edge length of the faces at size_min (NaN when none):
    the resolution the clamp actually produced, which a fixed mesh of equal resolution uses."""
    w_max = np.linalg.eigvalsh(0.5 * (face_M + np.swapaxes(face_M, 1, 2)))[:, -1]
    at_min = w_max >= (1.0 - BOUND_RTOL) / size_min**2
    at_max = w_max <= (1.0 + BOUND_RTOL) / size_max**2
    edge = math.nan
    if at_min.any():
        u = mesh.vert_u[mesh.face_verts[at_min]]  # (n, 3, 2)
        sides = np.linalg.norm(u - np.roll(u, -1, axis=1), axis=2)
        edge = float(np.median(sides))
    return {"faces_sized": int(len(face_M)), "faces_at_size_min": int(at_min.sum()),
            "faces_at_size_max": int(at_max.sum()), "edge_at_size_min_m": edge}


def face_to_vert_sizing(mesh: Mesh, face_M: np.ndarray) -> np.ndarray:
    """Area-weighted average of the sizing of the faces around each vert: (n_verts, 2, 2)."""
    w = mesh.face_area
    out = np.zeros((mesh.n_verts, 2, 2))
    total = np.zeros(mesh.n_verts)
    for k in range(3):
        np.add.at(out, mesh.face_verts[:, k], w[:, None, None] * face_M)
        np.add.at(total, mesh.face_verts[:, k], w)
    return out / total[:, None, None]


def face_edge_sizes(mesh: Mesh, vert_M: np.ndarray) -> np.ndarray:
    """(F, 3) edge size s of each face's sides (paper eq 1), side k from vert k to vert k+1.

    s^2(i, j) = u_ij^T ((M_i + M_j) / 2) u_ij with u_ij the material edge; s > 1 is an invalid
    edge that the remesher splits.
    """
    fv = mesh.face_verts
    a = fv.reshape(-1)
    b = np.roll(fv, -1, axis=1).reshape(-1)
    d = mesh.vert_u[b] - mesh.vert_u[a]
    M = 0.5 * (vert_M[a] + vert_M[b])
    return np.sqrt(np.einsum("ei,eij,ej->e", d, M, d)).reshape(-1, 3)
