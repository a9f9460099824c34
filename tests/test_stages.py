"""The stage plan: what a scene declares and what a mode asks for decide, in one place
(cloth.stages.plan_stages), which stages the frame loop calls; a stage that is not planned
is never called. Checked by replacing every stage's implementation with a counter."""

import pickle

import pytest
from helpers import COTTON

import cloth.simulation as simulation
from cloth.physics.buckling import BucklingParams
from cloth.remeshing.adaptive import AdaptiveRemesher
from cloth.scenes.registry import build_scene
from cloth.simulation import FORCE_EFFECTS, Simulation, Stages, plan_stages
from cloth.view.camera import Camera
from cloth.view.paths import StaticPath

# The stage implementations the frame loop calls through cloth.simulation's names.
STAGE_FUNCTIONS = {"obstacle_contact": "resolve_obstacle_contacts", "self_collision": "resolve_self_collisions",
                   "obstacle_ccd": "resolve_collisions_with_obstacles", "untangle": "untangle",
                   "buckling": "face_alpha"}
# Small scenes, one per combination of declared effects (a few hundred faces each).
SCENES = {
    "hanging_sheet": dict(resolution=6),  # membrane, bending, gravity, damping
    "flag": dict(resolution=6),  # + wind
    "sheet_on_sphere": dict(resolution=6),  # + analytic obstacles
    "layered_sheets": dict(resolution=5),  # + obstacles and self_collision
    "mesh_obstacle": dict(resolution=6, sphere_subdivisions=1),  # + a triangle-mesh obstacle
}
CAMERA = dict(position=(0.0, -3.0, 1.0), look_at=(0.0, 0.0, 0.5))


def counting(monkeypatch) -> dict:
    """Wrap every stage implementation with a call counter; returns the counts by stage."""
    calls = {stage: 0 for stage in STAGE_FUNCTIONS}
    for stage, name in STAGE_FUNCTIONS.items():
        real = getattr(simulation, name)

        def wrapper(*a, _stage=stage, _real=real, **k):
            calls[_stage] += 1
            return _real(*a, **k)

        monkeypatch.setattr(simulation, name, wrapper)
    return calls


def make(name: str, mode: str, effects=None) -> Simulation:
    params = dict(SCENES[name])
    if effects is not None:
        params["effects"] = effects
    scene = build_scene(name, COTTON, **params)
    remesher = AdaptiveRemesher() if mode in ("adaptive", "viewdep") else None
    buckling = None
    if mode == "viewdep":
        scene.camera = StaticPath(Camera(**CAMERA))
        buckling = BucklingParams(k=10.0)
    return Simulation(scene, remesher=remesher, buckling=buckling)


@pytest.mark.parametrize("mode", ["nonadaptive", "adaptive", "viewdep"])
@pytest.mark.parametrize("name", list(SCENES))
def test_a_stage_runs_exactly_when_the_scene_or_mode_asks_for_it(monkeypatch, name, mode):
    calls = counting(monkeypatch)
    sim = make(name, mode)
    effects = sim.scene.effects
    stages = sim.stages
    meshes = any(type(o).__name__ == "TriangleMeshObstacle" for o in sim.scene.obstacles)
    # the plan follows the declarations
    assert stages.forces == tuple(e for e in FORCE_EFFECTS if e in effects)
    assert [t.name for t in sim.terms] == list(stages.forces)
    assert stages.damping == ("damping" in effects)
    assert stages.obstacle_contact == ("obstacles" in effects)
    assert stages.self_collision == ("self_collision" in effects)
    assert stages.obstacle_ccd == meshes
    assert stages.remesh == (mode != "nonadaptive") and stages.buckling == (mode == "viewdep")
    assert stages.untangle == (stages.self_collision or meshes)
    for _ in range(2):
        sim.advance_frame()
    steps = 2 * sim.scene.steps_per_frame
    # what is not planned is never called; what is planned is called once per step (the remesh
    # stage may call contact and self-collision more: pushing new nodes out, keeping its motion
    # free of crossings; and buckling at every rebuild)
    per_step = {"obstacle_contact": stages.obstacle_contact, "obstacle_ccd": stages.obstacle_ccd,
                "self_collision": stages.self_collision and not stages.obstacle_ccd}
    for stage, planned in per_step.items():
        if not planned:
            assert calls[stage] == 0, stage
        elif stages.remesh:
            assert calls[stage] >= steps, stage
        else:
            assert calls[stage] == steps, stage
    assert (calls["buckling"] >= 2) if stages.buckling else (calls["buckling"] == 0)
    if not stages.untangle:
        assert calls["untangle"] == 0
    elif not stages.remesh:  # a fixed mesh checks its (clean) start state once, and never again
        assert calls["untangle"] == 1


def test_an_effect_left_out_of_the_list_costs_nothing(monkeypatch):
    """Scenes with one of their effects left out: none of its stages is called and none of its
    objects is built."""
    calls = counting(monkeypatch)
    sim = make("mesh_obstacle", "adaptive", effects=("membrane", "bending", "gravity"))  # no obstacles
    assert sim.stages == Stages(forces=("membrane", "bending", "gravity"), remesh=True)
    assert sim.contact is None and sim.obstacle_set is None and sim.mesh_obstacles == []
    assert sim.mesh_collision is None and sim.self_collision is None
    sim.advance_frame()
    sim = make("layered_sheets", "adaptive", effects=("membrane", "bending", "gravity", "obstacles"))
    assert not sim.stages.self_collision and not sim.stages.untangle and sim.self_collision is None
    for _ in range(2):
        sim.advance_frame()
    assert calls.pop("obstacle_contact") > 0  # the one effect declared in the second scene
    assert calls == {stage: 0 for stage in calls}


def test_stages_can_be_switched_off_by_name_and_unknown_names_are_refused():
    sim = make("mesh_obstacle", "nonadaptive")
    assert "obstacle_ccd" in sim.stages.names() and "force:gravity" in sim.stages.names()
    off = sim.stages.without("obstacle_ccd")
    assert not off.obstacle_ccd and off.obstacle_contact and off.forces == sim.stages.forces
    with pytest.raises(ValueError, match="unknown stage.*'wind_tunnel'"):
        sim.stages.without("wind_tunnel")
    with pytest.raises(ValueError, match="unknown stage.*'forces'"):
        sim.stages.without("forces")


def test_plan_is_a_pure_function_of_scene_and_mode():
    scene = build_scene("sheet_on_sphere", COTTON, resolution=4)
    assert plan_stages(scene) == plan_stages(scene)
    assert plan_stages(scene, AdaptiveRemesher()).remesh and not plan_stages(scene).remesh
    scene.thickness = 0.0  # no thickness: a triangle-mesh obstacle would get node contact only
    mesh_scene = build_scene("mesh_obstacle", COTTON, resolution=4, sphere_subdivisions=1, thickness=0.0)
    assert not plan_stages(mesh_scene).obstacle_ccd and plan_stages(mesh_scene).obstacle_contact
    assert plan_stages(mesh_scene, AdaptiveRemesher()).untangle  # crossings with the mesh can still arise
    assert plan_stages(mesh_scene).untangle  # and a fixed mesh's start state may cross it


def test_a_simulation_pickled_before_the_stage_plan_gets_its_plan_back():
    """Checkpoints of code before the plan existed hold no `stages`: unpickling plans them."""
    sim = make("layered_sheets", "adaptive")
    sim.advance_frame()
    state = dict(sim.__dict__)
    del state["stages"], state["intersections_pending"]
    old = Simulation.__new__(Simulation)
    old.__setstate__(state)
    assert old.stages == sim.stages and old.intersections_pending == 0
    again = pickle.loads(pickle.dumps(sim))
    assert again.stages == sim.stages
    again.advance_frame()
    sim.advance_frame()
    assert (again.mesh.node_x == sim.mesh.node_x).all()
