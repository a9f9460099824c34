"""Contact constraints inside the implicit solve (cloth.physics.integrator.ContactConstraints).

A node resting on an obstacle is held by the linear solve itself, so a large internal force on
a light node cannot carry it through the obstacle and sideways within one step (what broke
long adaptive runs, where coarse faces put light nodes at the corners of big faces); friction
comes from the constraint's normal impulse; a node whose forces pull it away lifts off.
"""

import numpy as np

from cloth.collision.obstacles import Plane
from cloth.core.material import Material
from cloth.core.mesh import grid_mesh
from cloth.core.scene import Scene
from cloth.physics.integrator import ContactConstraints, implicit_euler_step
from cloth.physics.linsolve import SolverOptions
from cloth.simulation import Simulation

COTTON = Material("cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3,
                  bending_stiffness=5e-6, damping_mass=0.0, damping_stiffness=0.0)
G = 9.81
THICKNESS = 0.005
# The constraint holds n . dv to ~1/CONSTRAINT_RATIO (1e-6) of the diagonal's scale plus the
# solver tolerance: below a micrometre per step here.
HOLD_M = 1e-6
# Friction: backward Euler's velocity is exact for a constant deceleration, up to the solver's
# tolerance (1e-8 relative requested below).
FRICTION_SPEED_TOL = 1e-5
TIGHT = SolverOptions(tolerance=1e-10, max_iterations=5000)


def _crushed_strip():
    """A 2 x 1 cell strip rising from the ground at 30 degrees, squeezed to 60 % of its length, far end pinned."""
    mesh = grid_mesh(0.04, 0.02, 2, 1, origin=(0, 0, THICKNESS))
    mesh.node_x[:, 0] *= 0.6
    mesh.node_x[:, 2] += np.tan(np.radians(30)) * mesh.node_x[:, 0]  # compression pushes the near end down
    far = mesh.vert_u[:, 0] > 0.03
    mesh.node_pinned[far] = True
    scene = Scene("crushed", mesh, COTTON, {"membrane"}, frame_time=0.04, steps_per_frame=1)
    return scene, mesh


def test_a_node_pushed_into_the_ground_is_held_by_the_solve_not_by_the_projection():
    scene, mesh = _crushed_strip()
    near = np.flatnonzero(mesh.vert_u[:, 0] < 1e-12)
    free = np.flatnonzero(~mesh.node_pinned)
    targets = mesh.node_x.copy()
    for constrained in (False, True):
        m = mesh.copy()
        contacts = None
        if constrained:
            contacts = ContactConstraints(near, np.tile([0.0, 0.0, 1.0], (near.size, 1)), np.zeros((near.size, 3)), 0.0)
        sim = Simulation(scene)
        s, _ = implicit_euler_step(m, sim.terms, sim.pattern, scene.dt, 0.0, 0.0, 0.0, targets, TIGHT, None, contacts)
        z = m.node_x[near, 2]
        if constrained:
            assert s.constrained == near.size
            assert np.all(np.abs(z - THICKNESS) < HOLD_M)
            assert np.all(m.node_x[free, 2] > 0)
        else:  # the failure the constraint exists for: the free solve drives the nodes through
            assert np.all(z < 0)


def test_a_sliding_sheet_decelerates_by_mu_g():
    mu, v0 = 0.3, 1.0
    mesh = grid_mesh(0.2, 0.2, 4, 4, origin=(0, 0, THICKNESS))
    mesh.node_v[:, 0] = v0
    scene = Scene("slide", mesh, COTTON, {"membrane", "gravity", "obstacles"}, frame_time=0.04, steps_per_frame=8,
                  obstacles=[Plane()], thickness=THICKNESS, friction=mu)
    sim = Simulation(scene, solver=SolverOptions(tolerance=1e-8, max_iterations=5000))
    for _ in range(5):  # 0.2 s, before the sheet stops (v0 / (mu g) = 0.34 s)
        sim.advance_frame()
    # implicit Euler: each step's normal impulse is m g h, so the speed drops by mu g h per step
    expected = v0 - mu * G * sim.time
    assert np.allclose(mesh.node_v[:, 0], expected, atol=FRICTION_SPEED_TOL)
    assert np.allclose(mesh.node_v[:, 1:], 0.0, atol=FRICTION_SPEED_TOL)
    assert np.allclose(mesh.node_x[:, 2], THICKNESS, atol=HOLD_M)


def test_a_sheet_lifted_by_its_handle_leaves_the_ground():
    mesh = grid_mesh(0.2, 0.2, 4, 4, origin=(0, 0, THICKNESS))
    up = 2.0  # m/s^2 upwards on top of gravity: the constraint must let go
    scene = Scene("lift", mesh, COTTON, {"membrane", "gravity", "obstacles"}, frame_time=0.04, steps_per_frame=8,
                  gravity=(0.0, 0.0, up), obstacles=[Plane()], thickness=THICKNESS, friction=0.5)
    sim = Simulation(scene)
    sim.advance_frame()
    t = sim.time
    # backward Euler from rest under a constant acceleration a: z = a h^2 n (n + 1) / 2
    n, h = scene.steps_per_frame, scene.dt
    assert np.allclose(mesh.node_x[:, 2], THICKNESS + up * h * h * n * (n + 1) / 2, atol=1e-9)
    assert np.allclose(mesh.node_v[:, 2], up * t, atol=1e-9)
