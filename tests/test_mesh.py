"""Mesh data model: derived topology invariants and validation messages."""

import numpy as np
import pytest

from cloth.core.mesh import Mesh, MeshError, grid_mesh

# Areas and masses are sums of a few hundred products of O(1) numbers.
ROUNDOFF = 1e-12


def _mesh(u, faces, vert_node=None, x=None):
    u = np.asarray(u, float)
    vert_node = np.arange(len(u)) if vert_node is None else np.asarray(vert_node)
    n = int(vert_node.max()) + 1
    if x is None:
        x = np.zeros((n, 3))
        x[vert_node, :2] = u
    return Mesh(node_x=x, node_v=np.zeros((n, 3)), node_pinned=np.zeros(n, bool),
                vert_u=u, vert_node=vert_node, face_verts=np.asarray(faces))


def test_grid_counts_and_adjacency_are_consistent():
    nx, ny = 5, 3
    m = grid_mesh(2.0, 1.0, nx, ny)
    assert m.n_faces == 2 * nx * ny
    assert m.n_nodes == (nx + 1) * (ny + 1)
    # Euler characteristic of a disc: V - E + F = 1
    assert m.n_nodes - m.n_edges + m.n_faces == 1
    assert np.sum(m.edge_faces[:, 1] < 0) == 2 * (nx + ny)
    # each face's three edges list that face among their two faces
    for f in range(m.n_faces):
        for e in m.face_edges[f]:
            assert f in m.edge_faces[e]
    # face A traverses (n0 -> n1) counter-clockwise; face B traverses it backwards
    for e in range(m.n_edges):
        n0, n1 = m.edge_nodes[e]
        fa, fb = m.edge_faces[e]
        ring = list(m.face_nodes[fa])
        k = ring.index(n0)
        assert ring[(k + 1) % 3] == n1 and ring[(k + 2) % 3] == m.edge_opp_nodes[e, 0]
        if fb >= 0:
            ring = list(m.face_nodes[fb])
            k = ring.index(n1)
            assert ring[(k + 1) % 3] == n0 and ring[(k + 2) % 3] == m.edge_opp_nodes[e, 1]
    assert abs(m.face_area.sum() - 2.0) < ROUNDOFF


def test_boundary_nodes_of_grid():
    m = grid_mesh(1.0, 1.0, 4, 4)
    u = m.vert_u[np.argsort(m.vert_node)]
    on_border = (np.isclose(u[:, 0], 0) | np.isclose(u[:, 0], 1) | np.isclose(u[:, 1], 0) | np.isclose(u[:, 1], 1))
    assert np.array_equal(m.node_boundary, on_border)


def test_mass_is_density_times_area():
    m = grid_mesh(1.5, 0.5, 6, 2)
    m.update_rest_data(0.2)
    assert abs(m.node_m.sum() - 0.2 * 0.75) < ROUNDOFF
    assert np.all(m.node_m > 0)


def test_seam_node_with_two_verts_shares_one_edge():
    # a band of three cells closed into a triangular prism: the verts at u = 1 are seam
    # copies of the nodes at u = 0
    u = [[0, 0], [1 / 3, 0], [2 / 3, 0], [1, 0], [0, 1], [1 / 3, 1], [2 / 3, 1], [1, 1]]
    faces = [[0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6]]
    vert_node = [0, 1, 2, 0, 3, 4, 5, 3]
    ang = np.array([0, 2, 4]) * np.pi / 3
    ring = np.column_stack([np.cos(ang), np.sin(ang), np.zeros(3)])
    x = np.vstack([ring, ring + [0, 0, 1]])
    m = _mesh(u, faces, vert_node, x)
    assert m.n_verts == 8 and m.n_nodes == 6
    # the seam edge (node 0 - node 3) is interior: it has two faces, so it carries bending
    seam = [e for e in range(m.n_edges) if set(m.edge_nodes[e]) == {0, 3}]
    assert len(seam) == 1 and m.edge_faces[seam[0], 1] >= 0
    assert m.node_boundary.all()  # every node of a one-cell-high band lies on an open rim
    assert m.n_nodes - m.n_edges + m.n_faces == 0  # Euler characteristic of an open cylinder
    assert m.edge_rest_length[seam[0]] == pytest.approx(1.0)


@pytest.mark.parametrize("faces, message", [
    ([[0, 1, 7]], "out-of-range vert index 7"),
    ([[0, 2, 1]], "inverted material triangle: face 0"),
    ([[0, 1, 3]], "degenerate material triangle: face 0"),
])
def test_validation_messages(faces, message):
    u = [[0, 0], [1, 0], [0, 1], [2, 0]]  # vert 3 is collinear with 0 and 1
    with pytest.raises(MeshError, match=message):
        _mesh(u, faces)


def test_non_manifold_edge_is_rejected():
    u = [[0, 0], [1, 0], [0.5, 1], [0.5, -1], [0.5, 2]]
    faces = [[0, 1, 2], [1, 0, 3], [0, 1, 4]]
    with pytest.raises(MeshError, match="non-manifold edge between nodes 0 and 1: shared by 3 faces"):
        _mesh(u, faces)


def test_inconsistent_orientation_across_a_seam_is_rejected():
    # two panels, each counter-clockwise in material space, sewn so that both traverse the
    # node edge 0 -> 1 in the same direction: one of them is flipped in the world
    u = [[0, 0], [1, 0], [0, 1], [3, 0], [4, 0], [3, 1]]
    match = r"faces 0 and 1 have inconsistent orientation across the edge between nodes \[0, 1\]"
    with pytest.raises(MeshError, match=match):
        Mesh(node_x=np.zeros((4, 3)), node_v=np.zeros((4, 3)), node_pinned=np.zeros(4, bool),
             vert_u=u, vert_node=[0, 1, 2, 0, 1, 3], face_verts=[[0, 1, 2], [3, 4, 5]])


def test_vert_to_missing_node_is_rejected():
    u = [[0, 0], [1, 0], [0, 1]]
    with pytest.raises(MeshError, match="maps to out-of-range node 5"):
        Mesh(node_x=np.zeros((3, 3)), node_v=np.zeros((3, 3)), node_pinned=np.zeros(3, bool),
             vert_u=u, vert_node=[0, 1, 5], face_verts=[[0, 1, 2]])


def test_grid_rejects_zero_resolution():
    with pytest.raises(MeshError, match="at least 1x1"):
        grid_mesh(1.0, 1.0, 0, 4)
