"""The ARCSim config reader (cloth.io.arcsim): every key on small configs, meshes and .mot files
written here (no ARCSim file is part of the repository), with poses computed by hand; plus one
test over ARCSim's own example scenes when ARCSIM_ROOT names an ARCSim checkout."""

from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np
import pytest
from arcsim_configs import (
    EXACT,
    SQUARE_OBJ,
    TETRA_OBJ,
    arcsim_dir,
    base,
    error_of,
    load,
    rot,
)

from cloth.io.arcsim import MAGIC_DEFAULTS, ArcsimConfigError, load_arcsim_config
from cloth.io.arcsim_json import strip_json_comments
from cloth.io.arcsim_mesh import read_arcsim_obj
from cloth.io.arcsim_motion import Transformation
from cloth.io.obj import ObjError

# ---- JSON with comments ---------------------------------------------------------------------------

def test_comments_are_blanked_but_markers_in_strings_survive():
    text = '{"a": "x//y /* z */", // line\n "b": /* block\n over lines */ 1}'
    stripped = strip_json_comments(text)
    assert len(stripped) == len(text) and stripped.count("\n") == text.count("\n")
    assert json.loads(stripped) == {"a": "x//y /* z */", "b": 1}
    assert json.loads(strip_json_comments(r'{"q": "say \"//\" \\", "r": 2} // end')) == {"q": 'say "//" \\', "r": 2}


@pytest.fixture
def root(tmp_path):
    """An ARCSim-like directory (arcsim_configs.arcsim_dir)."""
    return arcsim_dir(tmp_path)



def test_config_with_comments_and_double_slash_in_a_path_loads(root):
    text = """// a scene
{
    "frame_time": 0.04, /* the frame */ "frame_steps": 2,
    /* several
       lines */
    "cloths": [{"mesh": "meshes//square.obj", // a // inside the string stays
                "materials": [{"data": "materials/cotton.json"}]}]
}
"""
    conf = load(root, text)
    assert conf.cloths[0].mesh == root / "meshes" / "square.obj"
    assert conf.frame_steps == 2


def test_parse_errors_name_file_line_and_column(root):
    err = error_of(root, '{\n  "frame_time": 0.04,\n  "cloths": [}\n}')
    assert "line 3 column" in str(err)
    err = error_of(root, '{"frame_time": 0.04 /* never closed\n}')
    assert "line 1 column 21" in str(err) and "never closed" in str(err)
    err = error_of(root, '{"frame_time": 0.04, "frame_time": 0.05}')
    assert err.key == "frame_time" and "twice" in str(err)
    assert "not JSON" in str(error_of(root, '{"frame_time": NaN}'))


# ---- timing ---------------------------------------------------------------------------------------

def test_frame_time_form_and_defaults(root):
    conf = load(root, base(frame_steps=None, end_time=None))
    assert (conf.frame_time, conf.frame_steps, conf.step_time) == (0.04, 1, 0.04)
    assert conf.end_time == math.inf and conf.end_frame is None
    conf = load(root, base(frame_steps=8, end_time=None, end_frame=50))
    assert conf.step_time == 0.04 / 8 and conf.end_frame == 50 and conf.end_time == math.inf


def test_duration_is_the_end_time_in_both_forms(root):
    conf = load(root, base(end_time=None, duration=20))  # as flag.json writes it
    assert conf.end_time == 20 and conf.frame_time == 0.04
    conf = load(root, base(frame_time=None, frame_steps=None, end_time=None, timestep=0.002, save_frames=20,
                           duration=3))
    assert (conf.step_time, conf.frame_steps, conf.frame_time, conf.end_time) == (0.002, 20, 0.002 * 20, 3)
    assert conf.end_frame is None
    conf = load(root, base(frame_time=None, frame_steps=None, end_time=None, timestep=0.01))
    assert (conf.frame_steps, conf.frame_time, conf.end_time) == (1, 0.01, math.inf)


def test_timing_errors(root):
    assert error_of(root, base(duration=3)).key == "duration"  # with end_time
    assert error_of(root, base(timestep=0.01)).key == "timestep"  # two forms
    assert error_of(root, base(frame_time=None, frame_steps=None, timestep=0.01)).key == "end_time"
    assert error_of(root, base(frame_time=None)).key == "frame_time"  # no timing at all
    assert error_of(root, base(frame_steps=0)).key == "frame_steps"
    assert error_of(root, base(frame_steps=2.5)).key == "frame_steps"
    assert error_of(root, base(frame_time="0.04")).key == "frame_time"


# ---- cloths ---------------------------------------------------------------------------------------

def test_cloth_transform_is_scale_then_rotate_then_translate(root):
    cloth = {"mesh": "meshes/square.obj", "materials": [{"data": "materials/cotton.json"}],
             "transform": {"translate": [1, 2, 3], "rotate": [90, 0, 0, 5], "scale": 2}}
    c = load(root, base(cloths=[cloth])).cloths[0]
    # node 1 at (1, 0, 0): scaled (2, 0, 0), rotated 90 degrees about z (0, 2, 0), translated (1, 4, 3)
    np.testing.assert_allclose(c.node_x[1], [1, 4, 3], atol=EXACT)
    np.testing.assert_allclose(c.node_x, (2 * np.loadtxt(SQUARE_OBJ.splitlines()[1:5], usecols=(1, 2, 3))
                                          @ rot("z", 90).T) + [1, 2, 3], atol=EXACT)
    # the scale multiplies the material coordinates too (vt 2 0 -> 4 0)
    np.testing.assert_allclose(c.vert_u, [[0, 0], [4, 0], [4, 4], [0, 4]])
    np.testing.assert_array_equal(c.vert_node, [0, 1, 2, 3])
    np.testing.assert_array_equal(c.face_verts, [[0, 1, 2], [0, 2, 3]])  # a square's fans tie: corner 0
    np.testing.assert_array_equal(c.node_v, 0)
    assert c.transform.scale == 2 and c.n_nodes == 4


def test_transformation_composition_and_inverse():
    A = Transformation.from_config([1, 2, 3], [90, 0, 0, 1], 2)
    B = Transformation.from_config([0, 1, 0], [90, 1, 0, 0], 0.5)
    x = np.array([[0.3, -1.0, 2.0], [1.0, 0.0, 0.0]])
    np.testing.assert_allclose((A * B).apply(x), A.apply(B.apply(x)), atol=EXACT)
    np.testing.assert_allclose(A.inverse().apply(A.apply(x)), x, atol=EXACT)
    assert (A * B).scale == 1.0
    np.testing.assert_allclose((A * B).rotation_matrix(), rot("z", 90) @ rot("x", 90), atol=EXACT)
    np.testing.assert_allclose(A.apply_vector([1, 0, 0]), [0, 1, 0], atol=EXACT)  # neither scaled nor moved


def test_cloth_without_vt_gets_material_coordinates_from_x_and_y(root):
    cloth = {"mesh": "meshes/flat.obj", "materials": [{"data": "materials/cotton.json"}],
             "transform": {"scale": 3}, "velocity": {"linear": [1, 0, 0], "angular": [0, 0, 2], "origin": [0, 0, 15]}}
    c = load(root, base(cloths=[cloth])).cloths[0]
    np.testing.assert_allclose(c.vert_u, 3 * np.array([[0, 0], [2, 0], [2, 1], [0, 1]]))
    np.testing.assert_array_equal(c.face_verts, [[0, 1, 2], [0, 2, 3]])
    # v = linear + angular x (x - origin), x after the transform: node 2 at (6, 3, 15)
    np.testing.assert_allclose(c.node_v[2], [1 - 2 * 3, 2 * 6, 0])


def test_polygon_is_fanned_from_the_corner_with_the_largest_smallest_angle(tmp_path):
    # Fans over diagonal (-3,1)-(1,0) have a 14.04 degree angle (atan 1/4); fans over (0,0)-(1,1)
    # have at least 18.43 (atan 1/3): corners 1 and 3 tie, and corner 1 comes first.
    path = tmp_path / "kite.obj"
    path.write_text("v -3 1 0\nv 0 0 0\nv 1 0 0\nv 1 1 0\nf 1 2 3 4\n")
    np.testing.assert_array_equal(read_arcsim_obj(path).face_nodes, [[1, 2, 3], [1, 3, 0]])


def test_materials_and_remeshing(root):
    cloth = {"mesh": "meshes/square.obj",
             "materials": [{"data": "materials/cotton.json", "thicken": 2, "density_mult": 3, "stretching_mult": 0.5,
                            "bending_mult": 0.1, "damping": 1e-3, "strain_limits": [0.95, 1.05]}],
             "remeshing": {"refine_angle": 0.3, "refine_compression": 0.005, "refine_velocity": 0.5,
                           "size": [10e-3, 200e-3], "aspect_min": 0.2}}
    conf = load(root, base(cloths=[cloth]))
    m, r = conf.cloths[0].materials[0], conf.cloths[0].remeshing
    assert m.data == root / "materials" / "cotton.json"
    assert (m.density_factor, m.stretching_factor, m.bending_factor) == (6, 1, 0.2)
    assert (m.damping, m.strain_min, m.strain_max, m.strain_limited) == (1e-3, 0.95, 1.05, True)
    assert (r.refine_angle, r.refine_compression, r.refine_velocity) == (0.3, 0.005, 0.5)
    assert (r.size_min, r.size_max, r.aspect_min) == (10e-3, 200e-3, 0.2)
    assert "strainlimiting" not in conf.disabled_modules
    defaults = load(root, base())
    m, r = defaults.cloths[0].materials[0], defaults.cloths[0].remeshing
    assert (m.thicken, m.density_mult, m.damping, m.strain_min, m.strain_max) == (1, 1, 0, -math.inf, math.inf)
    assert (r.refine_angle, r.refine_velocity, r.size_min, r.size_max, r.aspect_min) == (
        math.inf, math.inf, -math.inf, math.inf, -math.inf)
    assert {"strainlimiting", "plasticity"} <= defaults.disabled_modules  # as ARCSim turns them off


# ---- handles and obstacles ------------------------------------------------------------------------

def test_handles(root):
    keys = [{"time": 0}, {"time": 1, "transform": {"translate": [0, 0, 1]}}]
    handles = [{"nodes": [2, 3], "end_time": 7},
               {"cloth": 0, "nodes": [0], "motion": 0, "start_time": 1, "end_time": 2, "fade_time": 0.5},
               {"type": "node", "nodes": [1], "motion": -1}]
    conf = load(root, base(motions=[keys], handles=handles))
    h0, h1, h2 = conf.handles
    np.testing.assert_array_equal(h0.nodes, [2, 3])
    assert (h0.cloth, h0.motion, h0.start_time, h0.end_time, h0.fade_time) == (0, None, 0, 7, 0)
    assert (h1.motion, h1.start_time, h1.end_time, h1.fade_time) == (0, 1, 2, 0.5)
    assert h2.motion is None
    assert [h1.strength(t) for t in (0.5, 1, 2, 2.6)] == [0, 1, 1, 0]
    assert h1.strength(2.25) == pytest.approx((1 - 0.25 / (0.5 + 1e-6)) ** 4)  # ARCSim's fade
    assert error_of(root, base(handles=[{"nodes": [4]}])).key == "handles[0].nodes[0]"  # 4 nodes: 0..3
    assert error_of(root, base(handles=[{"nodes": [0], "motion": 0}])).key == "handles[0].motion"
    assert error_of(root, base(handles=[{"nodes": [0], "cloth": 1}])).key == "handles[0].cloth"
    assert error_of(root, base(handles=[{"end_time": 1}])).key == "handles[0].nodes"
    err = error_of(root, base(handles=[{"type": "circle", "label": 1}]))
    assert err.key == "handles[0].type" and "not supported" in str(err)
    assert "'nodes'" in str(error_of(root, base(handles=[{"vertices": [2, 3]}])))  # sphere-annotated.json's key
    assert error_of(root, base(handles=[{"label": 1}])).key == "handles[0].label"


def test_obstacle_list(root):
    keys = [{"time": 0}, {"time": 1, "transform": {"translate": [0, 1, 0]}}]
    obstacles = [{"mesh": "meshes/tetra.obj", "transform": {"translate": [0, 0, -1], "scale": 2}},
                 {"mesh": "meshes/tetra.obj", "motion": 0, "start_time": 1.5, "end_time": 4}]
    conf = load(root, base(motions=[keys], obstacles=obstacles))
    o0, o1 = conf.obstacles
    assert o0.mesh == root / "meshes" / "tetra.obj" and conf.obstacle_pattern is None
    np.testing.assert_allclose(o0.node_x, [[0, 0, -1], [2, 0, -1], [0, 2, -1], [0, 0, 1]])
    np.testing.assert_array_equal(o0.face_nodes, [[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    assert (o0.motion, o0.start_time, o0.end_time) == (None, 0, math.inf)
    assert (o1.motion, o1.start_time, o1.end_time) == (0, 1.5, 4)
    assert error_of(root, base(obstacles=[{"mesh": "meshes/tetra.obj", "motion": 1}])).key == "obstacles[0].motion"
    assert error_of(root, base(obstacles=[{"mesh": "meshes/tetra.obj", "proxy": "floor"}])).key == "obstacles[0].proxy"


def test_obstacle_pattern_gives_one_obstacle_per_file_with_motion_i(root):
    (root / "meshes" / "body").mkdir()
    for i in range(3):
        (root / "meshes" / "body" / f"part{i:04d}.obj").write_text(TETRA_OBJ.replace("v 1 0 0", f"v {i + 1} 0 0"))
    (root / "meshes" / "body" / "part0004.obj").write_text(TETRA_OBJ)  # after a gap: not read
    keys = [{"time": 0}, {"time": 1}]
    conf = load(root, base(motions=[keys, keys], obstacles="meshes/body/part%04d.obj"))
    assert conf.obstacle_pattern == "meshes/body/part%04d.obj"
    assert [o.mesh.name for o in conf.obstacles] == ["part0000.obj", "part0001.obj", "part0002.obj"]
    assert [o.motion for o in conf.obstacles] == [0, 1, None]  # more files than motions: static
    assert [o.node_x[1, 0] for o in conf.obstacles] == [1, 2, 3]
    assert error_of(root, base(obstacles="meshes/body/part.obj")).key == "obstacles"  # no field
    assert error_of(root, base(obstacles="meshes/body/p%dart%d.obj")).key == "obstacles"  # two fields
    assert "does not exist" in str(error_of(root, base(obstacles="meshes/none%02d.obj")))


# ---- scene-wide keys ------------------------------------------------------------------------------

def test_gravity_wind_friction_disable_magic(root):
    conf = load(root, base(gravity=[0, 0, -9.8], wind={"velocity": [10, 0, 0], "density": 1.2, "drag": 0.1},
                           friction=0.4, obs_friction=0.2, disable=["popfilter", "remeshing"],
                           magic={"repulsion_thickness": 5e-3, "collision_stiffness": 1e6,
                                  "preserve_creases": True, "max_cracks": 4}))
    np.testing.assert_array_equal(conf.gravity, [0, 0, -9.8])
    np.testing.assert_array_equal(conf.wind.velocity, [10, 0, 0])
    assert (conf.wind.density, conf.wind.drag, conf.friction, conf.obs_friction) == (1.2, 0.1, 0.4, 0.2)
    assert conf.disable == frozenset({"popfilter", "remeshing"})
    assert conf.magic == {**MAGIC_DEFAULTS, "repulsion_thickness": 5e-3, "projection_thickness": 5e-4,
                          "collision_stiffness": 1e6, "preserve_creases": True, "max_cracks": 4}
    defaults = load(root, base())
    np.testing.assert_array_equal(defaults.gravity, 0)
    np.testing.assert_array_equal(defaults.wind.velocity, 0)
    assert (defaults.wind.density, defaults.wind.drag, defaults.friction, defaults.obs_friction) == (1, 0, 0.6, 0.3)
    assert defaults.disable == frozenset() and defaults.magic == MAGIC_DEFAULTS


def test_unknown_and_unsupported_keys_are_named(root):
    material = {"data": "materials/cotton.json"}
    cloth = {"mesh": "meshes/square.obj", "materials": [material]}
    cases = [
        (base(colour="red"), "colour", "unknown key"),
        (base(cloths=[{**cloth, "materials": [{**material, "thickness": 2}]}]), "cloths[0].materials[0].thickness",
         "not supported"),
        (base(cloths=[{**cloth, "materials": [{**material, "thicken_by": 2}]}]), "cloths[0].materials[0].thicken_by",
         "unknown key"),
        (base(cloths=[{**cloth, "materials": [{**material, "yield_curv": 200}]}]),
         "cloths[0].materials[0].yield_curv", "plasticity"),
        (base(disable=["strainlimiting", "gravity"]), "disable[1]", "unknown module"),
        (base(magic={"repulsion_thickness": 1e-3, "stiffness": 1}), "magic.stiffness", "unknown key"),
        (base(morphs=[]), "morphs", "not supported"),
        (base(obstacle_friction=0.3), "obstacle_friction", "'obs_friction'"),
        (base(cloths=[{**cloth, "remeshing": {"size_uniform": 1}}]), "cloths[0].remeshing.size_uniform",
         "not supported"),
        (base(wind={"speed": [1, 0, 0]}), "wind.speed", "unknown key"),
        (base(cloths=[{**cloth, "transform": {"translation": [1, 0, 0]}}]), "cloths[0].transform.translation",
         "unknown key"),
        (base(motions=[[{"time": 0, "transfrom": {}}]]), "motions[0][0].transfrom", "unknown key"),
        (base(cloths=[{**cloth, "materials": [material, material]}]), "cloths[0].materials", "exactly one"),
    ]
    for conf, key, words in cases:
        err = error_of(root, conf)
        assert err.key == key and words in str(err), (key, str(err))


def test_wrong_types_lengths_and_values_are_named(root):
    cloth = {"mesh": "meshes/square.obj", "materials": [{"data": "materials/cotton.json"}]}
    cases = [
        (base(gravity=[0, -9.8]), "gravity", "3 numbers"),
        (base(gravity=[0, "down", 0]), "gravity[1]", "number"),
        (base(cloths=[{**cloth, "transform": {"rotate": [90, 0, 1]}}]), "cloths[0].transform.rotate", "4 numbers"),
        (base(cloths=[{**cloth, "transform": {"rotate": [90, 0, 0, 0]}}]), "cloths[0].transform.rotate", "axis"),
        (base(cloths=[{**cloth, "transform": {"scale": 0}}]), "cloths[0].transform.scale", "> 0"),
        (base(cloths=[{**cloth, "materials": [{"data": "materials/cotton.json", "strain_limits": [0.9, 1, 1.1]}]}]),
         "cloths[0].materials[0].strain_limits", "2 numbers"),
        (base(cloths=[{**cloth, "remeshing": {"size": [0.2, 0.01]}}]), "cloths[0].remeshing.size", "min > max"),
        (base(cloths=[]), "cloths", "at least one"),
        (base(cloths=None), "cloths", "required"),
        (base(cloths=[{"mesh": "meshes/square.obj"}]), "cloths[0].materials", "required"),
        (base(magic={"combine_tensors": 1}), "magic.combine_tensors", "true or false"),
        (base(friction=-1), "friction", ">= 0"),
        (base(disable="popfilter"), "disable", "array"),
        (base(motions=[[{"time": 1}, {"time": 1}]]), "motions[0][1].time", "increase"),
        (base(motions=[[]]), "motions[0]", "at least one"),
        (base(motions={"motfile": "meshes/walk.mot"}), "motions.fps", "required"),
    ]
    for conf, key, words in cases:
        err = error_of(root, conf)
        assert err.key == key and words in str(err), (key, str(err))


def test_missing_and_unreadable_files_are_named(root):
    cloth = {"mesh": "meshes/square.obj", "materials": [{"data": "materials/cotton.json"}]}
    cases = [
        (base(cloths=[{**cloth, "mesh": "meshes/nope.obj"}]), "cloths[0].mesh", root / "meshes" / "nope.obj"),
        (base(cloths=[{**cloth, "materials": [{"data": "materials/silk.json"}]}]), "cloths[0].materials[0].data",
         root / "materials" / "silk.json"),
        (base(motions={"motfile": "meshes/run.mot", "fps": 30}), "motions.motfile", root / "meshes" / "run.mot"),
        (base(obstacles=[{"mesh": "meshes/rock.obj"}]), "obstacles[0].mesh", root / "meshes" / "rock.obj"),
    ]
    for conf, key, path in cases:
        err = error_of(root, conf)
        assert err.key == key and str(path) in str(err) and "no such file" in str(err)
    (root / "meshes" / "labelled.obj").write_text(SQUARE_OBJ + "nl 1\n")
    err = error_of(root, base(cloths=[{**cloth, "mesh": "meshes/labelled.obj"}]))
    assert err.key == "cloths[0].mesh" and "line 12" in str(err) and "'nl'" in str(err)
    (root / "meshes" / "empty.mot").write_text("")
    assert "empty" in str(error_of(root, base(motions={"motfile": "meshes/empty.mot", "fps": 30})))
    with pytest.raises(ArcsimConfigError, match="no such config"):
        load_arcsim_config(root / "conf" / "absent.json")


def test_root_defaults_to_the_parent_of_conf_and_can_be_given(root):
    assert load(root, base()).root == root  # root/conf/scene.json
    path = root / "scenes" / "deep" / "scene.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(base()))
    with pytest.raises(ArcsimConfigError, match="no such file") as info:
        load_arcsim_config(path)  # resolved against root/scenes
    assert str(root / "scenes" / "meshes" / "square.obj") in str(info.value)
    conf = load_arcsim_config(path, root=root)
    assert conf.root == root and conf.cloths[0].mesh == root / "meshes" / "square.obj"


def test_obj_reader_rejects_what_arcsim_cannot_read(tmp_path):
    path = tmp_path / "m.obj"
    for text, words in (("v 0 0 0\nv 1 0 0\nv 0 1 0\nf -3 -2 -1\n", "negative"),
                        ("v 0 0 0\nv 1 0 0\nf 1 2 3\nv 0 1 0\n", "stand above"),
                        ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
                        (SQUARE_OBJ + "vt 5 5\n", "belong to no face"),
                        ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nf 1/1 2/1 3/1\n", "one node"),
                        ("  v 0 0 0\n", "start the line")):
        path.write_text(text)
        with pytest.raises(ObjError, match=words):
            read_arcsim_obj(path)


# ---- ARCSim's own scenes --------------------------------------------------------------------------

ARCSIM_ROOT = os.environ.get("ARCSIM_ROOT")


@pytest.mark.skipif(not ARCSIM_ROOT, reason="set ARCSIM_ROOT to an ARCSim checkout (with conf/, meshes/, "
                                            "materials/) to load its example scenes")
def test_arcsim_example_scenes_load():
    root = Path(ARCSIM_ROOT)
    sphere = load_arcsim_config(root / "conf" / "sphere.json", root)
    assert sphere.motions[0].scale == 0.1 and sphere.obstacles[0].motion == 0
    np.testing.assert_array_equal(sphere.handles[0].nodes, [2, 3])
    flag = load_arcsim_config(root / "conf" / "flag.json", root)
    assert flag.end_time == 20 and flag.cloths[0].materials[0].thicken == 2
    dress = load_arcsim_config(root / "conf" / "dress-blue.json", root)
    assert dress.obstacle_pattern is not None and len(dress.obstacles) >= 1
    assert [o.motion for o in dress.obstacles] == [i if i < len(dress.motions) else None
                                                   for i in range(len(dress.obstacles))]
