"""Whole-simulation physical checks, in every mode where they apply (tests/helpers.MODES): free
fall, Rayleigh damping of a drift, momentum and energy of a free vibrating sheet, and a sheet
dropped on the sphere (no node inside an obstacle, no energy gained); the others in
mode=nonadaptive (force balance, the stiff-material case, determinism, effects, handles)."""

from types import SimpleNamespace

import numpy as np
import pytest
from helpers import COTTON, MEASURED_JSON, MODES, after_every_step, build_sim, mode_overrides, simulation_in_mode

import cloth.collision.contact
import cloth.physics.forces
import cloth.simulation
from cloth.core.material import Material
from cloth.core.mesh import grid_mesh
from cloth.core.scene import Scene
from cloth.physics.assembly import SparsityPattern
from cloth.physics.forces import Bending, ForceAccumulator, Gravity, Membrane, element_families
from cloth.physics.linsolve import SolverOptions
from cloth.scenes.registry import build_scene
from cloth.simulation import Simulation

# 100x the membrane and bending stiffness of denim: the stiff-material stability case.
STIFF = Material("stiff", density=0.4, youngs_modulus=2.0e6, poisson_ratio=0.3,
                 bending_stiffness=8e-3, damping_mass=0.0, damping_stiffness=0.0)
G = 9.81
# Positions after a few hundred steps of O(1) arithmetic agree to this (metres).
ROUNDOFF_M = 1e-9
# Internal forces of a deformed sheet cancel to round-off relative to their magnitude.
FORCE_BALANCE_REL = 1e-10
# The contact projection leaves nodes at phi = thickness up to round-off in the distance.
CONTACT_SLACK = 1e-9
# Central differences of a function linear in v are exact up to round-off (~1e-10 relative).
LINEAR_FD_TOL = 1e-8
# Lumped masses are thirds of face areas times the density: their sum is the sheet's mass to round-off.
MASS_ROUNDOFF_REL = 1e-12
# Energies are sums over at most a few thousand elements of terms below 1 J: they agree to this (J).
ENERGY_ROUNDOFF_J = 1e-12
# Linear momentum of a few hundred nodes (kg m/s, O(1e-2) in total) with the direct solver: round-off.
MOMENTUM_ROUNDOFF = 1e-14
# The drape below: sheet_on_sphere, 8 x 8 cells (adaptive: 8 cm finest edge), released 10 cm above
# the sphere's top so that it lands within DRAPE_FRAMES frames.
DRAPE = ("scene=sheet_on_sphere", "scene.scales.small.resolution=8", "scene.scales.small.sizing.size_min=0.08",
         "scene.params.drop_height=0.6", "output.rerun=false")
DRAPE_FRAMES = 8
SPHERE_C, SPHERE_R = np.array([0.0, 0.0, 0.25]), 0.25  # m, conf/scene/sheet_on_sphere.yaml
# "The cloth reached the obstacle": its closest node came within this many thicknesses of it.
REACHED_THICKNESSES = 2.0


@pytest.mark.parametrize("mode", MODES)
def test_free_fall_follows_g_t2_over_2(mode):
    """A flat sheet falls as one body in every mode: a remesh of it (here a coarsening) puts its
    new nodes on the same plane with the same velocity, and keeps its mass."""
    mesh = grid_mesh(0.5, 0.5, 6, 6, origin=(0, 0, 2.0))
    scene = Scene("fall", mesh, COTTON, {"membrane", "bending", "gravity"}, frame_time=0.04, steps_per_frame=4)
    sim = simulation_in_mode(scene, mode)
    z0 = mesh.node_x[0, 2]
    assert np.all(mesh.node_x[:, 2] == z0)  # flat: every node, old or new, starts at z0
    frames = 10
    for _ in range(frames):
        sim.advance_frame()
    t, h, n = sim.time, scene.dt, frames * scene.steps_per_frame
    dz = sim.mesh.node_x[:, 2] - z0
    # backward Euler: v_k = -g h k, x_n = x_0 - g h^2 n (n + 1) / 2 exactly (the sheet stays flat)
    assert np.allclose(dz, -G * h * h * n * (n + 1) / 2, atol=ROUNDOFF_M)
    # and that is g t^2 / 2 up to the method's first-order error g h t / 2
    assert np.allclose(dz, -G * t * t / 2, atol=G * h * t / 2 + ROUNDOFF_M)
    assert np.allclose(sim.mesh.node_v[:, 2], -G * t, atol=ROUNDOFF_M)
    assert sim.mesh.node_m.sum() == pytest.approx(COTTON.density * 0.5 * 0.5, rel=MASS_ROUNDOFF_REL)


@pytest.mark.parametrize("mode", MODES)
def test_rayleigh_mass_damping_slows_a_translation_by_the_implicit_euler_factor(mode):
    """A rigid translation has K v = 0, so only the mass-proportional term acts:
    m (1 + h alpha) dv = -h alpha m v, i.e. v_(k+1) = v_k / (1 + h alpha) exactly; the
    stiffness-proportional term alone leaves a rigid motion undamped. A remesh keeps a uniform
    velocity uniform."""
    from dataclasses import replace
    v0 = np.array([0.3, -0.2, 0.1])
    for material, factor in ((replace(COTTON, damping_mass=2.0, damping_stiffness=0.0), None),
                             (replace(COTTON, damping_mass=0.0, damping_stiffness=0.05), 1.0)):
        mesh = grid_mesh(0.5, 0.5, 6, 6)
        mesh.node_v[:] = v0
        scene = Scene("drift", mesh, material, {"membrane", "bending", "damping"}, frame_time=0.04, steps_per_frame=4)
        sim = simulation_in_mode(scene, mode)
        for _ in range(5):
            sim.advance_frame()
        n, h = 5 * scene.steps_per_frame, scene.dt
        expected = (1.0 + h * material.damping_mass) ** -n if factor is None else factor
        assert np.allclose(sim.mesh.node_v, v0 * expected, rtol=LINEAR_FD_TOL, atol=ROUNDOFF_M)


def test_rayleigh_stiffness_damping_drains_a_vibration():
    """A stretched sheet released without gravity oscillates; internal (stiffness-proportional)
    damping takes its energy away, and more of it with a larger beta."""
    from dataclasses import replace
    energies = []
    for beta in (0.0, 1e-4, 4e-4):  # s; beta omega = 0.08 and 0.3 for the ~8 ms period: underdamped
        mesh = grid_mesh(0.5, 0.5, 6, 6)
        mesh.update_rest_data(COTTON.density)
        mesh.node_x[:, 0] *= 1.05  # 5 % stretch in x, released from rest
        material = replace(COTTON, damping_mass=0.0, damping_stiffness=beta)
        # steps of 0.25 ms resolve the membrane's ~8 ms period, so that backward Euler's own
        # numerical damping does not take all the energy first
        scene = Scene("ring", mesh, material, {"membrane", "bending", "damping"}, frame_time=0.004, steps_per_frame=16)
        sim = Simulation(scene)
        for _ in range(3):
            rec = sim.advance_frame()
        energies.append(rec["kinetic_energy_j"] + rec["elastic_energy_j"])
    assert energies[0] > 1.5 * energies[1] > 1.5 * 1.5 * energies[2] > 0, energies


def _kinetic_energy(mesh) -> float:
    """1/2 sum m v^2 (J)."""
    return 0.5 * mesh.node_m @ np.einsum("ij,ij->i", mesh.node_v, mesh.node_v)


@pytest.mark.parametrize("mode", MODES)
def test_a_free_vibrating_sheet_keeps_its_momentum_and_never_gains_energy(mode):
    """No gravity, obstacle or handle: a stretched sheet released while drifting keeps its linear
    momentum (internal forces cancel; a remesh restores it, cloth.remeshing.adaptive.restore_momentum)
    and its total energy (kinetic + elastic, at each step's start) never grows from one step to
    the next: implicit Euler and stiffness damping take energy away, and so does a remesh with
    its pop filter. The direct solver makes both exact to round-off."""
    from dataclasses import replace
    mesh = grid_mesh(0.5, 0.5, 6, 6)
    mesh.update_rest_data(COTTON.density)
    mesh.node_x[:, 0] *= 1.05  # 5 % stretch in x
    mesh.node_v[:] = [0.3, -0.2, 0.1]  # m/s, a drift
    p0 = mesh.node_m @ mesh.node_v
    material = replace(COTTON, damping_mass=0.0, damping_stiffness=1e-4)
    scene = Scene("ring", mesh, material, {"membrane", "bending", "damping"}, frame_time=0.004, steps_per_frame=16)
    sim = simulation_in_mode(scene, mode, solver=SolverOptions(method="direct"))
    kinetic, energy, momentum = [], [], []

    def after(sim):  # the step's energy terms are evaluated at its start
        energy.append(kinetic[-1] + sum(sim.last_energy.values()))
        momentum.append(sim.mesh.node_m @ sim.mesh.node_v)

    after_every_step(sim, after, before=lambda sim: kinetic.append(_kinetic_energy(sim.mesh)))
    records = [sim.advance_frame() for _ in range(3)]
    assert np.abs(np.array(momentum) - p0).max() < MOMENTUM_ROUNDOFF
    rise = np.diff(energy)
    assert rise.max() <= ENERGY_ROUNDOFF_J, (int(rise.argmax()), rise.max())
    assert energy[-1] < 0.5 * energy[0]  # it vibrated and was damped
    if mode != "nonadaptive":  # the remeshes did change the mesh
        assert sum(r["remesh_splits"] + r["remesh_collapses"] for r in records) > 0


@pytest.fixture(scope="module", params=MODES)
def drape(request):
    """The sheet dropped on the sphere (DRAPE) for DRAPE_FRAMES frames in each mode; per step,
    at its end: the closest node's distance to the sphere and to the ground (m); at its start:
    the total energy and the kinetic plus gravitational energy (J). Run once per mode; the tests
    only read it."""
    sim = build_sim(*DRAPE, *mode_overrides(request.param))
    kinetic, total, falling, sphere, ground = [], [], [], [], []

    def after(sim):
        x = sim.mesh.node_x
        sphere.append((np.linalg.norm(x - SPHERE_C, axis=1) - SPHERE_R).min())
        ground.append(x[:, 2].min())
        total.append(kinetic[-1] + sum(sim.last_energy.values()))
        falling.append(kinetic[-1] + sim.last_energy["gravity"])

    after_every_step(sim, after, before=lambda sim: kinetic.append(_kinetic_energy(sim.mesh)))
    records = [sim.advance_frame() for _ in range(DRAPE_FRAMES)]
    return SimpleNamespace(mode=request.param, thickness=sim.scene.thickness, steps=sim.steps_taken, records=records,
                           sphere=np.array(sphere), ground=np.array(ground), total=np.array(total),
                           falling=np.array(falling))


def test_no_node_ends_a_step_inside_the_sphere_or_the_ground(drape):
    assert len(drape.sphere) == drape.steps  # every step was checked
    assert drape.sphere.min() >= drape.thickness - CONTACT_SLACK, int(drape.sphere.argmin())
    assert drape.ground.min() >= drape.thickness - CONTACT_SLACK, int(drape.ground.argmin())
    assert drape.sphere.min() < REACHED_THICKNESSES * drape.thickness  # the sheet did land on the sphere
    assert all(np.isfinite(r["kinetic_energy_j"]) for r in drape.records)


def test_kinetic_energy_never_exceeds_the_work_of_gravity(drape):
    """Gravity is the only input: the kinetic energy gained is at most the gravitational energy
    released (the elastic energy is never negative), in every mode."""
    assert drape.falling.max() <= drape.falling[0] + ENERGY_ROUNDOFF_J, int(drape.falling.argmax())


# Not in mode=viewdep: its buckling compensation (eq 11) changes the membrane energy of a face as
# it leaves or enters the frustum, so the total energy is not a quantity the view-dependent
# frame loop conserves (measured: up to 0.07 J above its start here).
@pytest.mark.parametrize("drape", ["nonadaptive", "adaptive"], indirect=True)
def test_total_energy_never_exceeds_its_start(drape):
    assert drape.total.max() <= drape.total[0] + ENERGY_ROUNDOFF_J, int(drape.total.argmax())


def test_forces_without_stiffness_match_the_assembled_forces():
    """add_forces (the pop filter's old-mesh forces) skips the Hessian's projection, not the force."""
    rng = np.random.default_rng(5)
    mesh = grid_mesh(1.0, 1.0, 6, 6)
    mesh.update_rest_data(0.1)
    mesh.node_x[:, :2] *= 0.8  # compressed: the membrane and bending Hessians need projection
    mesh.node_x += 0.03 * rng.standard_normal(mesh.node_x.shape)
    from cloth.core.measured import MeasuredMaterial
    from cloth.physics.forces import MeasuredBending, MeasuredMembrane

    knit = MeasuredMaterial("knit", MEASURED_JSON["density"], np.array(MEASURED_JSON["stretching"]),
                            np.array(MEASURED_JSON["bending"]))
    terms = [Membrane(*COTTON.lame()), Bending(1e-3), Gravity((0.0, 0.0, -9.81)), MeasuredMembrane(knit),
             MeasuredBending(knit)]
    pattern = SparsityPattern(mesh.n_nodes, element_families(mesh, terms))
    for term in terms:
        term.rebuild(mesh, pattern)
        acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
        term.accumulate(mesh, 0.0, acc)
        force = np.ones((mesh.n_nodes, 3))  # accumulates in place
        term.add_forces(mesh, 0.0, pattern, force)
        assert np.abs(acc.force).max() > 0, term.name
        tol = FORCE_BALANCE_REL * np.abs(acc.force).max()
        assert np.allclose(force - 1.0, acc.force, rtol=0.0, atol=tol), term.name


def test_internal_forces_sum_to_zero_on_a_deformed_sheet():
    rng = np.random.default_rng(4)
    mesh = grid_mesh(1.0, 1.0, 5, 5)
    mesh.update_rest_data(0.1)
    mesh.node_x += 0.05 * rng.standard_normal(mesh.node_x.shape)
    terms = [Membrane(*COTTON.lame()), Bending(1e-3)]
    pattern = SparsityPattern(mesh.n_nodes, element_families(mesh, terms))
    acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
    for term in terms:
        term.rebuild(mesh, pattern)
        term.accumulate(mesh, 0.0, acc)
    scale = np.abs(acc.force).max()
    assert scale > 0
    assert np.abs(acc.force.sum(0)).max() < FORCE_BALANCE_REL * scale * mesh.n_nodes
    torque = np.cross(mesh.node_x, acc.force).sum(0)
    assert np.abs(torque).max() < FORCE_BALANCE_REL * scale * mesh.n_nodes
    # the assembled stiffness is symmetric
    K = pattern.to_scipy(acc.K)
    assert abs(K - K.T).max() < FORCE_BALANCE_REL * abs(K).max()


def test_stiff_hanging_sheet_with_one_frame_steps_stays_finite_and_settles():
    scene = build_scene("hanging_sheet", STIFF, resolution=10, frame_time=1 / 30, steps_per_frame=1,
                        effects=("membrane", "bending", "gravity"))
    sim = Simulation(scene, max_speed=50.0)
    ke = [sim.advance_frame()["kinetic_energy_j"] for _ in range(150)]
    assert np.all(np.isfinite(sim.mesh.node_x))
    ke = np.asarray(ke)
    # the swing's energy peaks early; with one step per frame implicit Euler damps it out
    assert ke.max() > 0
    assert ke[-30:].mean() < 0.05 * ke.max()
    assert ke[-30:].mean() < ke[30:60].mean()


def test_draped_sheet_leaves_no_node_inside_sphere_or_ground():
    scene = build_scene("sheet_on_sphere", COTTON, resolution=14, effects=(
        "membrane", "bending", "gravity", "damping", "obstacles"))
    sim = Simulation(scene)
    sphere_c, sphere_r = np.array([0.0, 0.0, 0.25]), 0.25
    for _ in range(45):
        sim.advance_frame()
        x = sim.mesh.node_x
        d_sphere = np.linalg.norm(x - sphere_c, axis=1) - sphere_r
        assert d_sphere.min() >= scene.thickness - CONTACT_SLACK
        assert x[:, 2].min() >= scene.thickness - CONTACT_SLACK
    # it has landed: the centre rests on the sphere's top, the corners hang below it
    centre = np.argmin(np.linalg.norm(sim.mesh.node_x[:, :2], axis=1))
    assert sim.mesh.node_x[centre, 2] == pytest.approx(2 * sphere_r + scene.thickness, abs=0.01)
    assert sim.mesh.node_x[:, 2].min() < sphere_r


def _run_positions(seed):
    scene = build_scene("flag", COTTON, resolution=8, seed=seed)
    sim = Simulation(scene)
    for _ in range(10):
        sim.advance_frame()
    return sim.mesh.node_x.copy()


def test_two_runs_of_one_config_are_identical():
    a, b = _run_positions(3), _run_positions(3)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, _run_positions(4))  # the seed matters


def test_undeclared_effects_are_never_called(monkeypatch):
    calls = {"wind": 0, "contact": 0}
    wind_accumulate = cloth.physics.forces.Wind.accumulate
    contact = cloth.simulation.resolve_obstacle_contacts  # the frame loop's contact stage

    def counting_wind(self, *args):
        calls["wind"] += 1
        return wind_accumulate(self, *args)

    def counting_contact(*args, **kwargs):
        calls["contact"] += 1
        return contact(*args, **kwargs)

    monkeypatch.setattr(cloth.physics.forces.Wind, "accumulate", counting_wind)
    monkeypatch.setattr(cloth.simulation, "resolve_obstacle_contacts", counting_contact)
    sim = Simulation(build_scene("hanging_sheet", COTTON, resolution=6))
    for _ in range(3):
        sim.advance_frame()
    assert calls == {"wind": 0, "contact": 0}
    assert [t.name for t in sim.terms] == ["membrane", "bending", "gravity"]
    # the same counters do count when the effects are declared
    sim = Simulation(build_scene("flag", COTTON, resolution=6))
    sim.advance_frame()
    assert calls["wind"] == sim.scene.steps_per_frame
    sim = Simulation(build_scene("sheet_on_sphere", COTTON, resolution=6))
    sim.advance_frame()
    assert calls["contact"] == sim.scene.steps_per_frame


def test_handles_follow_their_prescribed_motion_exactly():
    from cloth.collision.obstacles import Oscillate
    from cloth.core.scene import Handle

    mesh = grid_mesh(0.6, 0.6, 6, 6, origin=(0, 0, 1.0))
    motion = Oscillate((0.2, 0.0, 0.1), 1.5)
    left = np.arange(7) * 7  # the column of nodes at u = 0
    start = mesh.node_x[left].copy()
    scene = Scene("handle", mesh, COTTON, {"membrane", "bending", "gravity", "damping"}, frame_time=1 / 30,
                  steps_per_frame=3, handles=[Handle(left, motion)])
    sim = Simulation(scene)
    for _ in range(10):
        sim.advance_frame()
        expected = start + motion.pose(sim.time)[1]
        assert np.abs(sim.mesh.node_x[left] - expected).max() < ROUNDOFF_M
    assert np.all(sim.mesh.node_pinned[left]) and np.all(np.isfinite(sim.mesh.node_x))


@pytest.mark.parametrize("mode", ["nonadaptive", "adaptive"])
def test_a_handle_holds_until_its_end_time_and_then_lets_go(mode):
    """ARCSim's handle end_time: pinned on their targets before it, free (falling) after it,
    whatever the remesher did to the nodes in between."""
    from cloth.collision.obstacles import Static
    from cloth.core.scene import Handle

    mesh = grid_mesh(0.6, 0.6, 6, 6, origin=(0, 0, 1.0))
    corners = np.array([0, 6])  # the corners at v = 0
    end_time = 0.1  # s: 3 frames of 1/30 s
    scene = Scene("release", mesh, COTTON, {"membrane", "bending", "gravity", "damping"}, frame_time=1 / 30,
                  steps_per_frame=3, handles=[Handle(corners, Static(), end_time=end_time)])
    held = mesh.node_x[corners].copy()
    sim = simulation_in_mode(scene, mode)
    handle = sim.scene.handles[0]
    for _ in range(3):
        sim.advance_frame()
        assert handle.nodes.size >= 2 and np.all(sim.mesh.node_pinned[handle.nodes])
        x = sim.mesh.node_x[handle.nodes]
        assert np.linalg.norm(x[:, None, :] - held[None], axis=2).min(axis=0).max() < ROUNDOFF_M
    sim.advance_frame()
    assert sim.time > end_time and handle.nodes.size == 0 and not sim.mesh.node_pinned.any()
    for _ in range(2):
        sim.advance_frame()
    assert sim.mesh.node_x[:, 2].max() < held[:, 2].min() - 0.01  # nothing holds the sheet up


def test_a_handle_that_ends_before_it_starts_is_named():
    from cloth.collision.obstacles import Static
    from cloth.core.scene import Handle, SceneError

    mesh = grid_mesh(0.6, 0.6, 2, 2)
    with pytest.raises(SceneError, match="end_time"):
        Scene("release", mesh, COTTON, {"membrane"}, frame_time=1 / 30, steps_per_frame=1,
              handles=[Handle(np.array([0]), Static(), end_time=0.0)])


def test_wind_drag_velocity_jacobian_matches_finite_differences():
    from cloth.physics.forces import drag_elements

    # the linear drags are linear in the velocities, so central differences are exact up to
    # round-off; the quadratic pressure's are exact up to round-off too (|v_n| v_n is quadratic
    # on each side of v_n = 0, which no face crosses within the step)
    rng = np.random.default_rng(2)
    mesh = grid_mesh(1.0, 1.0, 2, 2)
    x = mesh.node_x + 0.1 * rng.standard_normal(mesh.node_x.shape)
    v = rng.standard_normal(mesh.node_x.shape)
    wind, drag, density, tangential = np.array([3.0, 1.0, 0.5]), 0.7, 1.2, 0.3
    F = mesh.n_faces
    f0, J = np.empty((F, 9)), np.empty((F, 9, 9))
    drag_elements(x, v, mesh.face_nodes, wind, drag, density, tangential, f0, J)
    step = 1e-6
    for face in range(F):
        fd = np.empty((9, 9))
        for col in range(9):
            vp, vm = v.copy(), v.copy()
            vp[mesh.face_nodes[face, col // 3], col % 3] += step
            vm[mesh.face_nodes[face, col // 3], col % 3] -= step
            fp, fm, Jt = np.empty((F, 9)), np.empty((F, 9)), np.empty((F, 9, 9))
            drag_elements(x, vp, mesh.face_nodes, wind, drag, density, tangential, fp, Jt)
            drag_elements(x, vm, mesh.face_nodes, wind, drag, density, tangential, fm, Jt)
            fd[:, col] = -(fp[face] - fm[face]) / (2 * step)  # J = -df/dv
        assert np.abs(fd - J[face]).max() < LINEAR_FD_TOL * np.abs(J[face]).max()
        assert np.linalg.eigvalsh(J[face]).min() > -LINEAR_FD_TOL * np.abs(J[face]).max()


def test_arcsim_wind_force_on_a_hand_computed_face():
    """A face in the xy plane (normal +z, area 0.5) at rest in a wind (1, 0, 2) m/s: the normal part
    is A rho |v_n| v_n = 0.5 * 1.2 * 4 = 2.4 N along z, the tangential part A d v_t = 0.5 * 0.3 * 1
    = 0.15 N along x, a third of each on every node."""
    from cloth.physics.forces import drag_elements

    x = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    f, J = np.empty((1, 9)), np.empty((1, 9, 9))
    drag_elements(x, np.zeros((3, 3)), np.array([[0, 1, 2]]), np.array([1.0, 0.0, 2.0]), 0.0, 1.2, 0.3, f, J)
    assert np.allclose(f[0].reshape(3, 3), np.array([0.15, 0.0, 2.4]) / 3.0, rtol=0.0, atol=ROUNDOFF_M)


def test_a_solve_stopped_at_its_iteration_cap_is_recorded_and_noted(tmp_path):
    """An implicit step whose CG stops at solver.max_iterations above its tolerance is counted
    per frame (solves_capped), totalled in the summary and named in its notes; a converged run
    has none."""
    import json

    from helpers import QUIET, read_frames, run_config

    from cloth.physics.linsolve import solve_capped

    opts = SolverOptions(tolerance=1e-6, max_iterations=3)
    assert solve_capped(opts, 3, 1e-3) and not solve_capped(opts, 3, 1e-7) and not solve_capped(opts, 2, 1e-3)
    assert not solve_capped(SolverOptions(method="direct", max_iterations=1), 1, 1e-3)
    for cap, capped in ((2, True), (1000, False)):
        out = tmp_path / f"cap{cap}"
        summary = run_config(out, "frames=2", "solver=pcg", f"solver.max_iterations={cap}", *QUIET)
        frames = read_frames(out)
        assert (frames["solves_capped"] > 0).all() == capped and (frames["solves_capped"] > 0).any() == capped
        assert summary["solves_capped_total"] == int(frames["solves_capped"].sum())
        notes = json.loads((out / "summary.json").read_text())["notes"]
        assert any("iteration cap (solver.max_iterations = 2)" in n for n in notes) == capped


def test_a_scene_with_a_bad_self_thickness_is_named():
    from cloth.core.scene import SceneError

    for bad in (0.0, -1e-3):
        with pytest.raises(SceneError, match="self_thickness"):
            Scene("layers", grid_mesh(0.6, 0.6, 2, 2), COTTON, {"membrane"}, frame_time=1 / 30, steps_per_frame=1,
                  self_thickness=bad)


# The two bending Hessians give the same forces; a step of each differs only through the step's
# matrix, so a frame of the draped sheet ends within this of the other (metres; the frame's
# displacement is centimetres).
HESSIAN_CHOICE_M = 1e-3
# The Gauss-Newton kernel computes the same gradient with its own scalar arithmetic: equal forces
# up to round-off relative to the largest force.
FORCE_ROUNDOFF_REL = 1e-10


def _hessian_choices(key: str, term: str):
    """A fixed sheet built with solver.<key> projected and gauss_newton: the two simulations, each
    one's `project` of its <term> term, and that of the default build."""
    sims = {h: build_sim("scene=sheet_on_sphere", "mode=nonadaptive", "frames=1", f"solver.{key}={h}")
            for h in ("projected", "gauss_newton")}
    kinds = {h: [t.project for t in sim.terms if t.name == term] for h, sim in sims.items()}
    default = build_sim("scene=sheet_on_sphere", "mode=nonadaptive", "frames=1")
    return sims, kinds, [t.project for t in default.terms if t.name == term]


def test_the_gauss_newton_bending_hessian_is_the_solver_s_choice():
    """solver.bending_hessian=gauss_newton gives the bending term the Gauss-Newton Hessian (the
    default, BENDING_HESSIAN_DEFAULT) and projected the projected one; the forces are the same, and
    a frame of each stays finite and close to the other's."""
    from cloth.physics.membrane import GAUSS_NEWTON

    sims, kinds, default = _hessian_choices("bending_hessian", "bending")
    assert kinds["projected"] == [True] and kinds["gauss_newton"] == [GAUSS_NEWTON]
    assert default == [GAUSS_NEWTON]
    forces, bent = {}, None
    for h, sim in sims.items():  # at the start state moved out of plane (flat, every hinge is at rest)
        if bent is None:
            bent = sim.mesh.node_x + 1e-3 * np.random.default_rng(0).standard_normal(sim.mesh.node_x.shape)
        sim.mesh.node_x[:] = bent
        acc = ForceAccumulator.zeros(sim.mesh.n_nodes, sim.pattern)
        for t in sim.terms:
            t.accumulate(sim.mesh, 0.0, acc)
        (bending,) = [t for t in sim.terms if t.name == "bending"]
        forces[h] = acc.force.copy(), bending.hess.copy()
    (f, H), (f_gn, H_gn) = forces["projected"], forces["gauss_newton"]
    assert np.abs(f_gn - f).max() <= FORCE_ROUNDOFF_REL * np.abs(f).max()
    # the hinges' Hessians are what differs: by the term (theta - rest) Hess theta, not round-off
    assert np.abs(H_gn - H).max() > 1e-3 * np.abs(H).max()
    for sim in sims.values():
        sim.advance_frame()
    x = {h: s.mesh.node_x for h, s in sims.items()}
    assert np.isfinite(x["gauss_newton"]).all()
    assert np.abs(x["gauss_newton"] - x["projected"]).max() < HESSIAN_CHOICE_M


def test_the_gauss_newton_membrane_hessian_is_the_solver_s_option():
    """solver.membrane_hessian=gauss_newton gives the StVK membrane the Gauss-Newton Hessian (the
    stress's positive part in the geometric term: positive semi-definite, no eigen-decomposition);
    the default keeps the projected one; the forces are the same; a bad value names the key."""
    from cloth.physics.membrane import GAUSS_NEWTON
    from experiments.build import ConfigError

    sims, kinds, default = _hessian_choices("membrane_hessian", "membrane")
    assert kinds["projected"] == [True] and kinds["gauss_newton"] == [GAUSS_NEWTON]
    assert default == [True]
    rng = np.random.default_rng(1)
    squeezed = None
    out = {}
    for h, sim in sims.items():  # compressed in plane and moved out of it: indefinite element Hessians
        if squeezed is None:
            squeezed = sim.mesh.node_x * [0.8, 0.9, 1.0] + 1e-3 * rng.standard_normal(sim.mesh.node_x.shape)
        sim.mesh.node_x[:] = squeezed
        acc = ForceAccumulator.zeros(sim.mesh.n_nodes, sim.pattern)
        term = next(t for t in sim.terms if t.name == "membrane")
        term.accumulate(sim.mesh, 0.0, acc)
        out[h] = (acc.force.copy(), sim.pattern.to_scipy(acc.K).toarray())
    (f, K), (f_gn, K_gn) = out["projected"], out["gauss_newton"]
    assert np.array_equal(f, f_gn) and not np.allclose(K, K_gn)
    assert np.linalg.eigvalsh(0.5 * (K_gn + K_gn.T)).min() >= -1e-9 * np.abs(K_gn).max()
    with pytest.raises(ConfigError, match="solver.membrane_hessian"):
        build_sim("scene=sheet_on_sphere", "solver.membrane_hessian=exact")
