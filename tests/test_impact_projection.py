"""Impact zones that hold obstacle nodes are separated by inelastic projection
(cloth.collision.impactzones.inelastic_projection; Harmon et al. 2008, as ARCSim's): against
hand-computed projections, and on an obstacle that bends within the step, which no rigid motion
follows."""

import numpy as np
import pytest
from helpers import COTTON

from cloth.collision.impactzones import PROJECTION_SWEEPS, inelastic_projection, pinned_fit
from cloth.collision.meshobstacle import TriangleMeshObstacle
from cloth.collision.selfcollision import SelfCollisionParams, resolve_collisions_with_obstacles
from cloth.core.mesh import grid_mesh

# Hildreth's sweeps on one or two orthogonal constraints are exact up to round-off of metre-size
# coordinates.
ROUNDOFF = 1e-12
SEP = 0.01  # m, the separation asked of every impact in the hand-computed cases
TOLERANCE = 1e-9  # of SEP: run the sweeps to round-off in the hand-computed cases


def project(x, inv_m, hits, impacts):
    hits = np.asarray(hits, dtype=np.int64)
    impacts = np.asarray(impacts, dtype=np.float64)
    return inelastic_projection(x, np.asarray(inv_m, float), hits, impacts, np.arange(len(hits)), SEP,
                                PROJECTION_SWEEPS, TOLERANCE)


def test_a_node_under_a_fixed_face_is_moved_to_the_separation_and_no_farther():
    # node 0 at the height of the face (nodes 1-3, pinned) in the plane z = 0; it started above
    x = np.array([[0.2, 0.2, 0.0], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    w = [1.0, -0.6, -0.2, -0.2]  # the node's barycentric point on the face
    left = project(x, [1.0, 0.0, 0.0, 0.0], [[0, 1, 2, 3]], [[*w, 0.0, 0.0, 1.0]])
    assert x[0] == pytest.approx([0.2, 0.2, SEP], abs=ROUNDOFF)
    assert np.array_equal(x[1:], [[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])  # pinned
    assert left <= 0.0


def test_a_separated_impact_is_left_alone():
    x = np.array([[0.2, 0.2, 0.05], [0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    before = x.copy()
    project(x, [1.0, 0.0, 0.0, 0.0], [[0, 1, 2, 3]], [[1.0, -0.6, -0.2, -0.2, 0.0, 0.0, 1.0]])
    assert np.array_equal(x, before)


def test_two_impacts_on_one_node_meet_at_the_corner():
    # the node at the origin, a fixed floor (normal +z) and a fixed wall (normal +x): the least
    # move that separates both is to (SEP, 0, SEP)
    x = np.array([[0.0, 0.0, 0.0], [-1.0, -1.0, 0.0], [1.0, -1.0, 0.0], [0.0, 1.0, 0.0],
                  [0.0, -1.0, -1.0], [0.0, 1.0, -1.0], [0.0, 0.0, 1.0]])
    hits = [[0, 1, 2, 3], [0, 4, 5, 6]]
    impacts = [[1.0, -0.25, -0.25, -0.5, 0.0, 0.0, 1.0], [1.0, -0.25, -0.25, -0.5, 1.0, 0.0, 0.0]]
    project(x, [1.0] + [0.0] * 6, hits, impacts)
    assert x[0] == pytest.approx([SEP, 0.0, SEP], abs=ROUNDOFF)


def test_an_edge_pair_moves_its_free_nodes_by_their_weights_over_their_masses():
    # cloth edge 0-1 (masses 1 and 3 kg) crossing a fixed edge 2-3 at s = 0.25 on its own edge:
    # the least mass-weighted move lifts the point at s by SEP with dx_j = lambda w_j / m_j n
    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.25, -1.0, 0.0], [0.25, 1.0, 0.0]])
    inv_m = np.array([1.0, 1.0 / 3.0, 0.0, 0.0])
    w = np.array([0.75, 0.25, -0.5, -0.5])
    project(x, inv_m, [[0, 1, 2, 3]], [[*w, 0.0, 0.0, 1.0]])
    lam = SEP / float(np.sum(w ** 2 * inv_m))
    assert x[:2, 2] == pytest.approx(lam * w[:2] * inv_m[:2], abs=ROUNDOFF)
    assert float(w @ x[:, 2]) == pytest.approx(SEP, abs=ROUNDOFF)


def test_a_zone_against_a_bending_obstacle_is_separated():
    """A plate folds within one step (its two halves turn 40 degrees each way about the middle,
    their outer edges sweeping down through a sheet 1 cm below): no rigid motion fits its nodes,
    and the impact zones (no CCD passes before them) still leave no collision."""
    sheet = grid_mesh(0.4, 0.2, 8, 4, origin=(-0.2, -0.1, 0.0))
    sheet.update_rest_data(COTTON.density)
    y0 = np.array([[-0.15, -0.08, 0.01], [0.0, -0.08, 0.01], [0.15, -0.08, 0.01],
                   [-0.15, 0.08, 0.01], [0.0, 0.08, 0.01], [0.15, 0.08, 0.01]])
    plate = TriangleMeshObstacle(y0, [[0, 1, 4], [0, 4, 3], [1, 2, 5], [1, 5, 4]])
    a = np.radians(40.0)
    y1 = y0.copy()
    for k, side in ((0, -1.0), (3, -1.0), (2, 1.0), (5, 1.0)):  # the outer edges turn down about x = 0
        y1[k, 0] = side * 0.15 * np.cos(a)
        y1[k, 2] = 0.01 - 0.15 * np.sin(a)
    params = SelfCollisionParams(thickness=0.005, proximity_passes=0, ccd_passes=0)
    R, c0, c1 = pinned_fit(y0, y1)
    assert np.abs(c1 + (y0 - c0) @ R.T - y1).max() > 5 * params.thickness  # no rigid motion is near it
    x0 = sheet.node_x.copy()
    x1 = x0.copy()
    stats = resolve_collisions_with_obstacles(sheet.face_nodes, sheet.face_edges, sheet.edge_nodes, x0, x1,
                                              sheet.node_m, sheet.node_pinned, params,
                                              [(y0, y1, *plate.collision_topology())], self_pairs=False)
    assert stats["impact_zone_rounds"] >= 1 and stats["obstacle_collisions_left"] == 0
    # the nodes the folding halves reached were pushed down ahead of them (and outwards, along
    # the halves' tilted normals), none lifted
    moved = np.linalg.norm(x1 - x0, axis=1) > ROUNDOFF  # (the middle node moves by round-off)
    assert moved.any() and np.all(x1[moved, 2] < x0[moved, 2])
