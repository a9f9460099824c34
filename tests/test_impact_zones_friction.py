"""Self-collision response paths the other tests reach only by chance: rigid impact zones (when
the Gauss-Seidel CCD passes are not enough) and Coulomb friction between layers in contact."""

import numpy as np
from helpers import two_sheets

from cloth.collision.selfcollision import SelfCollisionParams, resolve_self_collisions
from cloth.collision.untangle import find_intersections

THICKNESS = 0.005
# Rigid impact zones move each zone by its mean displacement: momentum is kept to round-off.
MOMENTUM_TOL = 1e-12
# Without friction the repulsion is along the contact normal (z here): the sideways slide of the
# upper sheet is kept up to the tilt of the few normals near its edges (measured: 96 %).
SLIDE_KEPT = 0.9


def test_impact_zones_alone_stop_a_sheet_driven_through_another():
    mesh, n_lower = two_sheets()
    x0 = mesh.node_x.copy()
    x1 = x0.copy()
    x1[n_lower:, 2] -= 0.2  # ten times the gap in one step
    before = x1.copy()
    params = SelfCollisionParams(THICKNESS, ccd_passes=0)  # no Gauss-Seidel CCD: zones do it all
    stats = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                                    mesh.node_pinned, params)
    assert stats["impact_zones"] > 0 and stats["impact_zone_rounds"] >= 1
    assert stats["self_collisions_left"] == 0
    assert len(find_intersections(mesh.face_nodes, x1)[0]) == 0
    assert np.all(x1[n_lower:, 2] > x1[:n_lower, 2].min())  # the upper sheet stayed above
    m = mesh.node_m
    assert np.allclose(m @ x1, m @ before, rtol=0, atol=MOMENTUM_TOL)


def _slide(friction):
    """Mean sideways motion of the upper sheet sliding 4 mm while settling into contact."""
    mesh, n_lower = two_sheets(gap=0.006)
    x0 = mesh.node_x.copy()
    x1 = x0.copy()
    x1[n_lower:, 0] += 0.004
    x1[n_lower:, 2] -= 0.005  # ends 1 mm above the lower sheet, inside the thickness
    resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x0, x1, mesh.node_m,
                            mesh.node_pinned, SelfCollisionParams(THICKNESS, friction=friction))
    upper = slice(n_lower, None)
    return float(np.mean(x1[upper, 0] - x0[upper, 0]) - np.mean(x1[:n_lower, 0] - x0[:n_lower, 0]))


def test_friction_between_layers_resists_sliding():
    free, sticky = _slide(0.0), _slide(1.0)
    assert free >= SLIDE_KEPT * 0.004
    assert sticky < 0.5 * free  # mu = 1 against a 4 mm push into contact: most of the slide is gone
