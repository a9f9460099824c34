"""Strain limiting (cloth.physics.strainlimiting) and its stage: the limits hold after the stage,
pinned nodes stay, a mesh within its limits is untouched, velocities take the displacement, and a
scene that does not declare the effect never calls it."""

import numpy as np
import pytest
from helpers import COTTON, after_every_step, write_material

import cloth.simulation as simulation
from cloth.core.measured import load_arcsim_material
from cloth.core.mesh import grid_mesh
from cloth.core.scene import Scene, SceneError
from cloth.physics.assembly import SparsityPattern
from cloth.physics.strainlimiting import STRAIN_TOLERANCE, face_violation, limit_strain, principal_stretches
from cloth.scenes.registry import hanging_sheet
from cloth.simulation import Simulation, plan_stages

LIMITS = (0.95, 1.05)  # ARCSim's flag and garments
# A sheet's momentum after the stage: the Newton steps keep sum w (y - x) = 0 up to the
# factorisation's residual (SOLVE_TOLERANCE, 1e-9, relative), far below this.
MOMENTUM_TOL = 1e-7
SEED = 5


@pytest.fixture
def material(tmp_path):
    return load_arcsim_material(write_material(tmp_path / "knit.json"), strain_limits=LIMITS)


def _sheet(n, stretch, pins, jitter=0.002, squeeze=None):
    """An n x n sheet, 0.5 m across, stretched by `stretch` along u (and by `squeeze` along v,
    default 1 + 0.3 (stretch - 1)), with a little out-of-plane noise; `pins`: 'corners' (the two
    corners at v = 0.5 m, at their rest places), 'edge' (the column u = 0), or 'none'."""
    mesh = grid_mesh(0.5, 0.5, n, n)
    mesh.update_rest_data(0.2)
    rest = mesh.node_x.copy()
    x = rest.copy()
    x[:, 0] *= stretch
    x[:, 1] *= 1.0 + 0.3 * (stretch - 1.0) if squeeze is None else squeeze
    x[:, 2] += jitter * np.random.default_rng(SEED).standard_normal(mesh.n_nodes)
    if pins == "corners":
        mesh.node_pinned[[n * (n + 1), (n + 1) * (n + 1) - 1]] = True
    elif pins == "edge":
        mesh.node_pinned[np.isclose(mesh.vert_u[:, 0], 0.0)] = True
    x[mesh.node_pinned] = rest[mesh.node_pinned]
    mesh.node_x[:] = x
    return mesh


def _stretches(mesh):
    """(F, 2) principal stretches of every face."""
    out = np.empty((mesh.n_faces, 2))
    for f, (i, j, k) in enumerate(mesh.face_nodes):
        F = np.column_stack([mesh.node_x[j] - mesh.node_x[i], mesh.node_x[k] - mesh.node_x[i]]) @ mesh.face_Dm_inv[f]
        out[f, 0], out[f, 1], _ = principal_stretches(F)
    return out


def _limit(mesh, limits=LIMITS):
    return limit_strain(mesh, SparsityPattern(mesh.n_nodes, {"faces": mesh.face_nodes}), *limits)


@pytest.mark.parametrize("n, stretch, pins", [(12, 1.2, "edge"), (12, 1.1, "corners"), (16, 1.1, "none"),
                                              (12, 1.5, "edge"), (12, 0.8, "edge")])
def test_the_limits_hold_after_the_stage_and_pins_stay(n, stretch, pins):
    mesh = _sheet(n, stretch, pins)
    before = mesh.node_x.copy()
    s = _stretches(mesh)
    assert s.max() > LIMITS[1] + 0.02 or s.min() < LIMITS[0] - 0.02  # well beyond the limits
    r = _limit(mesh)
    s = _stretches(mesh)
    assert s[:, 0].max() <= LIMITS[1] + STRAIN_TOLERANCE
    assert s[:, 1].min() >= LIMITS[0] - STRAIN_TOLERANCE
    assert r["strain_violation_max"] <= STRAIN_TOLERANCE and r["strain_limit_iterations"] > 0
    pinned = mesh.node_pinned
    assert np.array_equal(mesh.node_x[pinned], before[pinned])


def test_a_sheet_within_its_limits_is_untouched():
    mesh = _sheet(10, 1.03, "none", squeeze=0.97)
    before = mesh.node_x.copy()
    r = _limit(mesh)
    assert r == {"strain_limit_iterations": 0, "strain_violation_max": 0.0}
    assert np.array_equal(mesh.node_x, before)


def test_a_free_sheet_keeps_its_momentum():
    """Without pins the mass-weighted objective moves the nodes about their centre of mass."""
    mesh = _sheet(10, 1.15, "none")
    before = mesh.node_x.copy()
    _limit(mesh)
    shift = mesh.node_m @ (mesh.node_x - before)
    assert np.linalg.norm(shift) <= MOMENTUM_TOL * mesh.node_m.sum() * np.abs(mesh.node_x - before).max()


def test_unsatisfiable_limits_are_reported():
    """Two pinned corners 10 % further apart than at rest: the top row cannot reach 5 %."""
    mesh = _sheet(8, 1.0, "corners", jitter=0.0)
    n = 8
    mesh.node_x[(n + 1) * (n + 1) - 1, 0] += 0.05
    r = _limit(mesh)
    assert r["strain_violation_max"] > 10 * STRAIN_TOLERANCE
    violation = np.empty(mesh.n_faces)
    assert face_violation(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, *LIMITS, violation) == \
        r["strain_violation_max"]


# ---- the stage in the frame loop ---------------------------------------------------------------

def _hanging(material, limited=True, resolution=8):
    effects = ("membrane", "bending", "gravity") + (("strain_limiting",) if limited else ())
    return hanging_sheet(material, resolution=resolution, size=0.4, effects=effects)


def test_the_stage_holds_the_limits_in_a_hanging_sheet(material):
    """A soft sheet (a tenth of the knit's stretching) sags beyond 5 % under its weight without
    the stage; with it, every step ends within the limits."""
    soft = load_arcsim_material(material.source, stretching_mult=0.1, strain_limits=LIMITS)
    free = Simulation(_hanging(load_arcsim_material(material.source, stretching_mult=0.1), limited=False))
    for _ in range(4):
        free.advance_frame()
    assert face_violation(free.mesh.node_x, free.mesh.face_nodes, free.mesh.face_Dm_inv, *LIMITS,
                          np.empty(free.mesh.n_faces)) > 0.02
    sim = Simulation(_hanging(soft))
    worst = []
    after_every_step(sim, lambda s: worst.append(face_violation(s.mesh.node_x, s.mesh.face_nodes, s.mesh.face_Dm_inv,
                                                                *LIMITS, np.empty(s.mesh.n_faces))))
    for _ in range(4):
        record = sim.advance_frame()
        assert np.all(np.isfinite(sim.mesh.node_x))
    assert max(worst) <= STRAIN_TOLERANCE
    assert 0 < record["strain_limit_iterations"] and record["strain_violation_max"] <= STRAIN_TOLERANCE


def test_the_stage_adds_the_displacement_to_the_velocities(material):
    sim = Simulation(_hanging(material))
    mesh = sim.mesh
    mesh.node_x[:, 0] *= 1.2  # stretched beyond the limits
    mesh.node_x[mesh.node_pinned, 0] /= 1.2
    x0, v0 = mesh.node_x.copy(), mesh.node_v.copy()
    stats = {"strain_limit_iterations": 0, "strain_violation_max": 0.0}
    sim.limit_strain(stats)
    assert stats["strain_limit_iterations"] > 0
    assert np.allclose(mesh.node_v - v0, (mesh.node_x - x0) / sim.dt, rtol=0, atol=1e-12)
    assert np.array_equal(mesh.node_x[mesh.node_pinned], x0[mesh.node_pinned])


def test_the_stage_costs_nothing_when_not_declared(monkeypatch, material):
    calls = []
    real = simulation.limit_strain

    def counting(*a, **k):
        calls.append(1)
        return real(*a, **k)

    monkeypatch.setattr(simulation, "limit_strain", counting)
    plain = load_arcsim_material(material.source)  # no strain limits
    sim = Simulation(_hanging(plain, limited=False))
    assert not sim.stages.strain_limiting and "strain_limiting" not in sim.stages.names()
    record = sim.advance_frame()
    assert calls == [] and record["strain_limit_iterations"] == 0 and record["strain_violation_max"] == 0.0
    sim = Simulation(_hanging(material))
    assert plan_stages(sim.scene).strain_limiting and "strain_limiting" in sim.stages.names()
    sim.advance_frame()
    assert len(calls) == sim.scene.steps_per_frame
    assert not sim.stages.without("strain_limiting").strain_limiting


def test_the_scene_checks_the_effect_against_the_limits(material):
    plain = load_arcsim_material(material.source)
    mesh = grid_mesh(0.3, 0.3, 3, 3)
    effects = {"membrane", "bending", "strain_limiting"}
    with pytest.raises(SceneError, match="'strain_limiting' is declared.*no strain_limits"):
        Scene("s", mesh, plain, frozenset(effects), frame_time=0.04, steps_per_frame=2)
    with pytest.raises(SceneError, match="strain_limits.*does not declare the effect 'strain_limiting'"):
        Scene("s", mesh, material, frozenset({"membrane", "bending"}), frame_time=0.04, steps_per_frame=2)
    with pytest.raises(SceneError, match="strain_limiting"):  # the isotropic material has no limits at all
        Scene("s", mesh, COTTON, frozenset(effects), frame_time=0.04, steps_per_frame=2)
    Scene("s", mesh, material, frozenset(effects), frame_time=0.04, steps_per_frame=2)
