"""scene=arcsim: an ARCSim configuration run by this tool (cloth/scenes/arcsim.py).

Every file is written here, in ARCSim's formats: a square sheet with texture coordinates, a
measured material (made-up numbers of the right shapes), a sphere obstacle on a keyframed motion.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from helpers import MEASURED_JSON, QUIET, compose_config, read_frames, run_config, write_material

from cloth.core.scene import SceneError
from cloth.io.states import load_state
from cloth.scenes.arcsim import arcsim_remesher_overrides, arcsim_scene
from cloth.scenes.bodies import icosphere
from experiments.build import ConfigError, build_simulation

pytestmark = pytest.mark.slow  # the quick tier, pytest -m "not slow", leaves this module out

FRAME_TIME = 0.04  # s, the constructed scene's frame (ARCSim's 25 fps)
ROUNDOFF_M = 1e-9  # m, positions compared after a few float operations
# A node may sit this far inside the contact thickness at the end of a frame (the projection leaves
# it at the thickness up to the last collision pass's tolerance); never inside the obstacle itself.
CONTACT_SLACK_M = 1e-4


def _write_scene(root: Path, **top) -> Path:
    """An ARCSim-style folder under `root` (conf/, meshes/, materials/) and its conf; `top` keys
    replace or add the conf's top-level keys (None removes one)."""
    for sub in ("conf", "meshes", "materials"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    (root / "meshes" / "square.obj").write_text(
        "v -0.3 -0.3 0.3\nv 0.3 -0.3 0.3\nv 0.3 0.3 0.3\nv -0.3 0.3 0.3\n"
        "vt 0 0\nvt 0.6 0\nvt 0.6 0.6\nvt 0 0.6\nf 1/1 2/2 3/3\nf 1/1 3/3 4/4\n")
    v, f = icosphere(1.0, 2)
    lines = [f"v {x:.9f} {y:.9f} {z:.9f}" for x, y, z in v] + [f"f {a + 1} {b + 1} {c + 1}" for a, b, c in f]
    (root / "meshes" / "sphere.obj").write_text("\n".join(lines) + "\n")
    write_material(root / "materials" / "test-knit.json",
                   text="// a made-up knit\n" + json.dumps(MEASURED_JSON))  # density 0.2 kg/m^2
    conf = {
        "frame_time": FRAME_TIME, "frame_steps": 4, "end_time": 0.2,
        "cloths": [{"mesh": "meshes/square.obj",
                    "materials": [{"data": "materials/test-knit.json", "thicken": 2}],
                    "remeshing": {"refine_angle": 0.3, "refine_compression": 0.01, "refine_velocity": 1,
                                  "size": [0.05, 0.3], "aspect_min": 0.2}}],
        "handles": [{"nodes": [2, 3], "end_time": 0.1}],
        "motions": [[{"time": 0, "transform": {"scale": 0.12, "translate": [0, 0, 0]}},
                     {"time": 1, "transform": {"scale": 0.12, "translate": [0, 0.1, 0]}}]],
        "obstacles": [{"mesh": "meshes/sphere.obj", "motion": 0}],
        "gravity": [0, 0, -9.8],
        "magic": {"repulsion_thickness": 5e-3, "collision_stiffness": 1e6},
    }
    for key, value in top.items():
        if value is None:
            conf.pop(key, None)
        else:
            conf[key] = value
    path = root / "conf" / "test.json"
    path.write_text("// constructed for the tests\n" + json.dumps(conf, indent=1))
    return path


def _min_obstacle_distance(scene, x, t) -> float:
    ob = scene.obstacles[0]
    ob.set_time(t)
    phi, _, _ = ob.query(x)
    return float(phi.min())


def test_the_scene_is_what_the_conf_says(tmp_path):
    conf = _write_scene(tmp_path)
    scene = arcsim_scene(conf=str(conf))
    assert scene.mesh.n_faces == 2 and scene.steps_per_frame == 4 and scene.frame_time == FRAME_TIME
    # ARCSim always has air (density 1 by default); no strain limits, no damping, collisions on
    assert scene.effects == {"membrane", "bending", "gravity", "wind", "obstacles", "self_collision"}
    assert scene.material.density == pytest.approx(0.4)  # 0.2 kg/m^2 x thicken 2
    assert scene.thickness == 5e-3 and scene.friction == 0.3 and scene.self_friction == 0.6  # ARCSim's defaults
    # between cloth layers ARCSim's hard projection thickness: 0.1 x the repulsion thickness
    assert scene.self_thickness == pytest.approx(5e-4)
    assert not any("projection_thickness" in n for n in scene.notes)
    given = _write_scene(tmp_path / "given", magic={"repulsion_thickness": 5e-3, "projection_thickness": 1e-3})
    assert arcsim_scene(conf=str(given)).self_thickness == pytest.approx(1e-3)
    assert [h.nodes.tolist() for h in scene.handles] == [[2], [3]] and scene.handles[0].end_time == 0.1
    assert scene.wind.density == 1.0 and scene.wind.drag == 0.0
    assert any("collision_stiffness" in n for n in scene.notes)
    # the obstacle: the unit sphere scaled by the motion's 0.12, moving along y by 0.1 m in 1 s
    ob = scene.obstacles[0]
    for t, centre_y in ((0.0, 0.0), (1.0, 0.1)):
        ob.set_time(t)
        phi, _, _ = ob.query(np.array([[0.0, centre_y, 0.5]]))
        assert phi[0] == pytest.approx(0.5 - 0.12, abs=0.12 * 0.05)  # facets of a level-2 icosphere
    sizing = arcsim_remesher_overrides(str(conf), size_factor=2.0)["sizing"]
    assert sizing["size_min"] == pytest.approx(0.1) and sizing["size_max"] == pytest.approx(0.3)
    assert sizing["refine_angle"] == 0.3 and sizing["aspect_min"] == 0.2


def test_the_fixed_mesh_is_uniform_keeps_the_handles_and_starts_outside_the_obstacle(tmp_path):
    conf = _write_scene(tmp_path)
    edge = 0.05
    scene = arcsim_scene(conf=str(conf), mode_mesh="uniform", fixed_edge=edge)
    mesh = scene.mesh
    lengths = np.linalg.norm(np.diff(mesh.vert_u[mesh.face_verts][:, [0, 1, 2, 0]], axis=1), axis=2)
    assert lengths.max() <= edge * (1 + 1e-9) and mesh.n_faces >= 2 * (0.6 / edge) ** 2
    corners = np.array([[0.3, 0.3, 0.3], [-0.3, 0.3, 0.3]])
    for h, corner in zip(scene.handles, corners, strict=True):
        assert h.nodes.size == 1 and np.abs(mesh.node_x[h.nodes[0]] - corner).max() < ROUNDOFF_M
    assert _min_obstacle_distance(scene, mesh.node_x, 0.0) >= scene.thickness - ROUNDOFF_M


@pytest.mark.parametrize(("top", "key"), [
    ({"magic": {"rib_stiffening": 2.0}}, "magic.rib_stiffening"),
    ({"handles": [{"nodes": [2], "start_time": 0.3, "end_time": 0.2}]}, "handles[0]"),
    ({"obstacles": [{"mesh": "meshes/sphere.obj", "motion": 0, "end_time": 1}]}, "obstacles[0]"),
    ({"disable": ["physics"]}, "physics"),
])
def test_what_this_tool_does_not_do_is_named(tmp_path, top, key):
    conf = _write_scene(tmp_path, **top)
    with pytest.raises(SceneError, match=key.replace("[", r"\[").replace("]", r"\]")):
        arcsim_scene(conf=str(conf))


def test_a_bad_key_stops_the_run_before_any_work_naming_key_and_file(tmp_path):
    conf = _write_scene(tmp_path, gravty=[0, 0, -9.8])
    out = tmp_path / "run"
    with pytest.raises(ConfigError, match=r"gravty.*test\.json|test\.json.*gravty"):
        run_config(out, "scene=arcsim", f"scene.params.conf={conf}", *QUIET)
    assert not (out / "frames.parquet").exists()


def test_effects_follow_disable_and_the_air_and_a_list_keeps_only_those(tmp_path):
    conf = _write_scene(tmp_path, disable=["collision"], wind={"density": 0, "drag": 0})
    assert arcsim_scene(conf=str(conf)).effects == {"membrane", "bending", "gravity", "obstacles"}
    conf = _write_scene(tmp_path)
    assert arcsim_scene(conf=str(conf), effects=("membrane", "gravity", "obstacles")).effects == {
        "membrane", "gravity", "obstacles"}
    with pytest.raises(SceneError, match="strain_limiting"):
        arcsim_scene(conf=str(conf), effects=("membrane", "strain_limiting"))


def test_frames_default_to_the_conf_end_and_the_sizes_to_the_conf(tmp_path):
    conf = _write_scene(tmp_path)
    cfg = compose_config("scene=arcsim", f"scene.params.conf={conf}", "mode=adaptive", "scale=paper")
    sim, n_frames = build_simulation(cfg)
    assert n_frames == 5  # end_time 0.2 s at 0.04 s per frame
    assert sim.remesher.sizing.size_min == 0.05 and sim.remesher.sizing.size_max == 0.3
    conf = _write_scene(tmp_path, end_time=None)
    with pytest.raises(ConfigError, match="frames"):
        build_simulation(compose_config("scene=arcsim", f"scene.params.conf={conf}"))


@pytest.mark.parametrize("mode", ["nonadaptive", "adaptive", "viewdep"])
def test_five_frames_of_a_constructed_scene_in_each_mode(tmp_path, mode):
    """The conf's end (5 frames), nothing left inside the sphere, the handle let go at 0.1 s."""
    conf = _write_scene(tmp_path)
    camera = ("camera=fixed", "camera.position=[1.2,-1.2,0.9]", "camera.target=[0,0,0.2]")
    out = tmp_path / f"run_{mode}"
    summary = run_config(out, "scene=arcsim", f"scene.params.conf={conf}", f"mode={mode}", "scale=paper",
                         "output.states_every=1", "output.checkpoint_every=2",  # the scene pickles
                         *(camera if mode == "viewdep" else ()), *QUIET)
    assert summary["frames_completed"] == 5
    frames = read_frames(out)
    assert frames["faces"].min() > 2  # the 2-triangle input refined (fixed mesh: at build time)
    scene = arcsim_scene(conf=str(conf))
    paths = sorted((out / "states").glob("frame_*.npz"))
    assert len(paths) == 6  # frame 0 and the five frames
    for path in paths:
        state = load_state(path)
        assert _min_obstacle_distance(scene, state["node_x"], float(state["time"])) > -CONTACT_SLACK_M
    last = load_state(paths[-1])
    assert not np.any(last["node_pinned"])  # released at its end_time


def test_a_fast_obstacle_gets_substeps_so_that_it_moves_at_most_half_the_thickness_per_step(tmp_path):
    """Two keys 1 s apart with zero end tangents (ARCSim's Hermite): the ball's speed is
    1.9 m x (6 t - 6 t^2), 2.85 m/s at t = 0.5 s; over a 0.04 s frame that is 0.114 m, 45.6 half
    thicknesses (2.5 mm): 46 steps instead of the conf's 4 where the sheet is within its reach. A
    ball that cannot reach the sheet within the frame (the first frame's, 18 cm below it at 0.44 m/s,
    and the fast ball 0.5 m or 10 m away) asks for none, and a ball at rest keeps the conf's 4."""
    from cloth.simulation import Simulation

    motions = [[{"time": 0, "transform": {"scale": 0.12}},
                {"time": 1, "transform": {"scale": 0.12, "translate": [0, 1.9, 0]}}]]
    scene = arcsim_scene(conf=str(_write_scene(tmp_path, motions=motions)))
    assert scene.obstacle_step == 0.5
    sim = Simulation(scene)
    sim.time = 0.0
    assert sim.advance_frame()["steps"] == 4  # the ball 18 cm under the sheet moves 1.8 cm this frame
    sim.time = 0.5
    assert sim.obstacle_steps() == 1  # the ball 0.5 m off the sheet's box: it cannot reach it this frame
    x = sim.mesh.node_x.copy()
    sim.mesh.node_x[:, 1] += 0.95  # the sheet over the ball at t = 0.5 s (y = 0.95 m), 3 cm above its top
    sim.mesh.node_x[:, 2] = 0.15
    assert sim.obstacle_steps() == 46
    sim.mesh.node_x[:] = x + [10.0, 0.0, 0.0]  # 10 m aside
    assert sim.obstacle_steps() == 1
    still = [[{"time": 0, "transform": {"scale": 0.12}}, {"time": 1, "transform": {"scale": 0.12}}]]
    sim = Simulation(arcsim_scene(conf=str(_write_scene(tmp_path, motions=still))))
    assert sim.obstacle_steps() == 1 and sim.advance_frame()["steps"] == 4


def test_a_failed_run_to_the_conf_end_resumes_to_it(tmp_path, monkeypatch):
    """frames=null: the run and its resume both go to the conf's end (5 frames)."""
    from cloth.simulation import Simulation
    from experiments import resume as resume_mod

    conf = _write_scene(tmp_path)
    original, calls = Simulation.advance_frame, [0]

    def crash_at_the_fourth(self):
        calls[0] += 1
        if calls[0] == 4:
            raise RuntimeError("simulated crash")
        return original(self)

    out = tmp_path / "run"
    with monkeypatch.context() as m:
        m.setattr(Simulation, "advance_frame", crash_at_the_fourth)
        with pytest.raises(RuntimeError, match="simulated crash"):
            run_config(out, "scene=arcsim", f"scene.params.conf={conf}", "scale=paper", "output.checkpoint_every=2",
                       *QUIET)
    assert len(read_frames(out)) == 3
    summary = resume_mod.resume(out, progress=False)
    assert summary["status"] == "completed" and summary["frames_completed"] == 5


def test_a_handle_that_starts_late_and_fades_runs_its_phases(tmp_path):
    """ARCSim's start_time and fade_time: the corner is free until 0.08 s (frame 2's end), pinned
    from the step that starts then, fading after 0.12 s with magic handle_stiffness, then released."""
    handles = [{"nodes": [2], "start_time": 0.08, "end_time": 0.12, "fade_time": 0.04}]
    conf = _write_scene(tmp_path, handles=handles,
                        magic={"repulsion_thickness": 5e-3, "handle_stiffness": 400.0})
    h = arcsim_scene(conf=str(conf)).handles[0]
    assert (h.start_time, h.end_time, h.fade_time, h.stiffness) == (0.08, 0.12, 0.04, 400.0)
    out = tmp_path / "run"
    summary = run_config(out, "scene=arcsim", f"scene.params.conf={conf}", "mode=adaptive", "scale=paper",
                         "output.states_every=1", *QUIET)
    assert summary["frames_completed"] == 5
    pinned = [bool(load_state(p)["node_pinned"].any()) for p in sorted((out / "states").glob("frame_*.npz"))]
    assert pinned == [False, False, False, True, False, False]


def test_seed_0_is_the_confs_own_mesh_and_other_seeds_move_only_the_free_nodes(tmp_path):
    """An ARCSim scene's seed: 0 starts from the conf's mesh (what ARCSim's output is compared
    with); s > 0 adds seeded noise of ARCSIM_JITTER to the nodes no handle holds, the same for the
    same seed. A bad seed or jitter is refused naming it."""
    from cloth.scenes.arcsim import ARCSIM_JITTER

    conf = str(_write_scene(tmp_path))
    base = arcsim_scene(conf=conf, mode_mesh="uniform", fixed_edge=0.1)
    x0 = base.mesh.node_x
    held = np.concatenate([h.nodes for h in base.handles])
    np.testing.assert_array_equal(arcsim_scene(conf=conf, mode_mesh="uniform", fixed_edge=0.1, seed=0).mesh.node_x, x0)
    one = arcsim_scene(conf=conf, mode_mesh="uniform", fixed_edge=0.1, seed=1).mesh.node_x
    again = arcsim_scene(conf=conf, mode_mesh="uniform", fixed_edge=0.1, seed=1).mesh.node_x
    two = arcsim_scene(conf=conf, mode_mesh="uniform", fixed_edge=0.1, seed=2).mesh.node_x
    np.testing.assert_array_equal(one, again)
    assert np.abs(one - two).max() > 0
    np.testing.assert_array_equal(one[held], x0[held])
    free = np.setdiff1d(np.arange(len(x0)), held)
    d = one[free] - x0[free]
    assert np.all(d != 0)
    assert np.abs(d).max() <= 6 * ARCSIM_JITTER  # a normal deviate beyond 6 sigma: odds 1e-9 a draw
    for bad in ({"seed": -1}, {"jitter": -1e-4}, {"jitter": float("nan")}):
        with pytest.raises(SceneError, match=next(iter(bad))):
            arcsim_scene(conf=conf, **bad)
