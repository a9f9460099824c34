"""Stiffness of a measured material (cloth.core.measured) at a face's strain and at a hinge's
curvature, evaluated as ARCSim evaluates it (src/dde.cpp; the data-driven elastic model of Wang,
Ramamoorthi and O'Brien 2011).

Stretching: the stiffness (k0, k1, k2, k3) of a face is the trilinear interpolation of the
material's tabulated samples (30^3, cloth.core.measured.stretching_samples) at its Green strain
G = 1/2 (F^T F - I), on the axes

    a = 30 (G00 + 1/4),  b = 30 (G11 + 1/4),  c = 30 |G01|,

each clamped to [0, 29 - 1e-5] (:func:`stretching_stiffness`). The sign of G01 is dropped: a
principal direction at +phi and at -phi from the material u axis get the same stiffness.

Bending: the stiffness ke of a hinge (:func:`bending_stiffness`) interpolates the material's
3 x 5 samples bilinearly in

    v = (theta l / (A_0 + A_1)) / 10 m^-1       (curvature; clamped above at 4, not below),
    d = the edge's direction in material space, folded into [0, 2] (0: along u, 1: at 45
        degrees, 2: along v; :func:`edge_direction`),

with theta ARCSim's signed dihedral angle now (ARCSim's edge->theta, refreshed after each
step's collisions: the step's start), l the rest length of the edge and A_0, A_1 the rest areas
of its faces, and clamps the result at 0. ARCSim's theta is the opposite of this project's
(cloth.physics.bending.dihedral_angle: positive when the hinge folds away from face A's normal;
ARCSim's sine is taken about the edge's other direction), so theta_ARCSim = -theta here. ARCSim
clamps v from above only: a hinge with theta_ARCSim < 0 extrapolates the first two curvature
samples linearly below zero (its integer part truncates towards zero), so that folds of one
sense get a different stiffness from folds of the other. This module keeps that, as ARCSim
runs. Each hinge evaluates ke once for each of its faces (a seam may give the edge two
directions) and takes the smaller (src/physics.cpp).

ARCSim's single-precision atan2f and fabsf are rounded to single precision here too.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

from cloth.core.measured import STRETCH_G_MIN, STRETCH_SAMPLES
from cloth.physics.bending import dihedral_angle

# Upper clamp of the stretching table's axes (so that the trilinear cell stays in the table).
STRETCH_AXIS_CLAMP = STRETCH_SAMPLES - 1 - 1e-5
# ARCSim's bending samples are 10 m^-1 apart in theta l / (A_0 + A_1) (its alpha = curv / 2 in
# steps of 5 m^-1), and its curvature coordinate stops at the last of the five.
CURVATURE_STEP = 10.0  # m^-1
CURVATURE_CLAMP = 4.0


@njit(cache=True)
def stretching_stiffness(G00, G01, G11, samples, out):
    """(k0, k1, k2, k3) in N/m at the Green strain G, into out (4,): the trilinear interpolation of
    `samples` (30, 30, 30, 4) at a = 30 (G00 + 1/4), b = 30 (G11 + 1/4), c = 30 |G01| (clamped)."""
    n = STRETCH_SAMPLES
    a = (G00 - STRETCH_G_MIN) * n
    b = (G11 - STRETCH_G_MIN) * n
    # fabsf(G(0,1)) * nsamples: single precision, as in ARCSim
    c = np.float64(np.float32(abs(G01)) * np.float32(n))
    a = min(max(a, 0.0), STRETCH_AXIS_CLAMP)
    b = min(max(b, 0.0), STRETCH_AXIS_CLAMP)
    c = min(max(c, 0.0), STRETCH_AXIS_CLAMP)
    ai = min(max(int(math.floor(a)), 0), n - 2)
    bi = min(max(int(math.floor(b)), 0), n - 2)
    ci = min(max(int(math.floor(c)), 0), n - 2)
    a -= ai
    b -= bi
    c -= ci
    for m in range(4):
        out[m] = 0.0
    for i in range(2):
        wa = a if i else 1.0 - a
        for j in range(2):
            wb = b if j else 1.0 - b
            for k in range(2):
                w = wa * wb * (c if k else 1.0 - c)
                for m in range(4):
                    out[m] += samples[ai + i, bi + j, ci + k, m] * w


@njit(cache=True)
def edge_direction(du0, du1):
    """ARCSim's folded direction of a material edge (du0, du1), in [0, 2]: 0 along u, 1 at 45
    degrees, 2 along v (|atan2| 4 / pi, reflected about 2; atan2 in single precision)."""
    d = np.float64(np.float32(math.atan2(np.float64(np.float32(du1)), np.float64(np.float32(du0))))) * 4.0 / math.pi
    if d < 0.0:
        d = -d
    if d > 4.0:
        d = 8.0 - d
    if d > 2.0:
        d = 4.0 - d
    return d


@njit(cache=True)
def bending_stiffness(curvature, direction, bending):
    """ke in N m at ARCSim's signed curvature theta l / (A_0 + A_1) (1/m) of an edge with folded
    material direction `direction` (:func:`edge_direction`), from `bending` (3, 5) N m: bilinear
    in v = curvature / 10 (clamped above at 4 only) and the direction, clamped at >= 0."""
    v = curvature / CURVATURE_STEP
    if v > CURVATURE_CLAMP:
        v = CURVATURE_CLAMP
    vi = min(max(int(v), 0), 3)  # int() truncates towards zero, as C's cast
    v -= vi
    di = min(max(int(direction), 0), 1)
    d = direction - di
    ke = (bending[di, vi] * (1.0 - d) * (1.0 - v) + bending[di + 1, vi] * d * (1.0 - v)
          + bending[di, vi + 1] * (1.0 - d) * v + bending[di + 1, vi + 1] * d * v)
    return max(ke, 0.0)


@njit(cache=True, parallel=True)
def hinge_stiffness(node_x, edge_stencil, edge_length, edge_area_sum, edge_direction_ab, bending, out_ke, out_weight):
    """Per hinge (E,): ARCSim's stiffness ke (N m) at its curvature now, and its weight
    w = ke l^2 / (4 (A_0 + A_1)) in W = 1/2 w (theta - theta_rest)^2 (N m).

    `edge_stencil` (E, 4) as cloth.physics.bending; `edge_length` (E,) m, ARCSim's rest length
    (the mean of the two faces' material lengths); `edge_area_sum` (E,) m^2; `edge_direction_ab`
    (E, 2) the folded material direction of the edge in face A and in face B. ke is the smaller
    of the two faces' stiffness at the curvature -theta l / (A_0 + A_1) (module docstring).
    """
    for e in prange(edge_stencil.shape[0]):
        s = edge_stencil[e]
        theta = -dihedral_angle(node_x[s[0]], node_x[s[1]], node_x[s[2]], node_x[s[3]])  # ARCSim's sign
        curvature = theta * edge_length[e] / edge_area_sum[e]
        ke = min(bending_stiffness(curvature, edge_direction_ab[e, 0], bending),
                 bending_stiffness(curvature, edge_direction_ab[e, 1], bending))
        out_ke[e] = ke
        out_weight[e] = ke * edge_length[e] * edge_length[e] / (4.0 * edge_area_sum[e])


def hinge_rest_data(mesh):
    """ARCSim's rest data of the mesh's hinges (cloth.core.mesh.Mesh.bending_edges, in order):
    (edge_length (E,) m, the mean of the edge's material length in its two faces;
    edge_area_sum (E,) m^2, A_0 + A_1; edge_direction_ab (E, 2), the folded material direction of
    the edge n0 -> n1 in face A and in face B, :func:`edge_direction`)."""
    idx = mesh.bending_edges
    nodes = mesh.edge_nodes[idx]
    faces = mesh.edge_faces[idx]
    du = np.empty((idx.size, 2, 2))
    for side in range(2):
        fv = mesh.face_verts[faces[:, side]]  # (E, 3) verts of the face on this side
        fn = mesh.vert_node[fv]
        k0 = np.argmax(fn == nodes[:, :1], axis=1)
        k1 = np.argmax(fn == nodes[:, 1:], axis=1)
        rows = np.arange(idx.size)
        du[:, side] = mesh.vert_u[fv[rows, k1]] - mesh.vert_u[fv[rows, k0]]
    length = 0.5 * (np.linalg.norm(du[:, 0], axis=1) + np.linalg.norm(du[:, 1], axis=1))
    area = mesh.face_area[faces[:, 0]] + mesh.face_area[faces[:, 1]]
    direction = np.empty((idx.size, 2))
    edge_directions(du, direction)
    return np.ascontiguousarray(length), np.ascontiguousarray(area), direction


@njit(cache=True)
def edge_directions(du, out):
    """:func:`edge_direction` of every material edge vector du (..., 2), into out (...)."""
    flat_du = du.reshape(-1, 2)
    flat_out = out.reshape(-1)
    for i in range(flat_out.shape[0]):
        flat_out[i] = edge_direction(flat_du[i, 0], flat_du[i, 1])
