"""One source of every scene default: a scene builder's defaults are its conf/scene/<name>.yaml
(`params`, and `scales.small.resolution`, the default scale's), so that `build_scene(name,
material)` from Python is the scene `python -m experiments.run scene=<name>` runs."""

import inspect

import numpy as np
import pytest
import yaml
from helpers import ROOT, compose_config

from cloth.scenes.crowd import multiple_dancers
from cloth.scenes.dancers import solo_dancer
from cloth.scenes.registry import CROWDS, SCENES, build_scene
from experiments.build import build_simulation

# conf/scene/arcsim.yaml reads an ARCSim JSON file; its values are that file's, not defaults
SCENE_CONFS = sorted(p.stem for p in (ROOT / "conf" / "scene").glob("*.yaml") if p.stem != "arcsim")


def _conf(name: str) -> dict:
    return yaml.safe_load((ROOT / "conf" / "scene" / f"{name}.yaml").read_text())


def _builder_defaults(name: str) -> dict:
    """The defaults of the parameters build_scene(name, ...) takes (a crowd: its own and solo_dancer's)."""
    builders = (multiple_dancers, solo_dancer) if name in CROWDS else (SCENES[name],)
    out = {}
    for b in builders:
        for k, p in inspect.signature(b).parameters.items():
            if p.default is not inspect.Parameter.empty and k not in out:
                out[k] = p.default
    return out


def _same(a, b) -> bool:
    """Equal, to the last bit (a tuple default and a YAML list compare by their items)."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    return type(a) is type(b) and a == b or (isinstance(a, (int, float)) and isinstance(b, (int, float))
                                            and not isinstance(a, bool) and not isinstance(b, bool) and a == b)


def test_every_scene_conf_is_a_registered_builder():
    assert {_conf(n)["name"] for n in SCENE_CONFS} <= set(SCENES)
    assert set(SCENE_CONFS) == {_conf(n)["name"] for n in SCENE_CONFS}  # file name = scene name


@pytest.mark.parametrize("name", SCENE_CONFS)
def test_builder_defaults_are_the_conf_values(name):
    conf = _conf(name)
    defaults = _builder_defaults(name)
    given = dict(conf.get("params") or {})
    small = (conf.get("scales") or {}).get("small") or {}
    if "resolution" in small:
        given["resolution"] = small["resolution"]
    missing = sorted(set(given) - set(defaults))
    assert not missing, f"conf/scene/{name}.yaml sets {missing}, which the builder does not take"
    differ = {k: (v, defaults[k]) for k, v in given.items() if not _same(v, defaults[k])}
    assert not differ, f"conf/scene/{name}.yaml (value, builder default): {differ}"
    assert _same(list(conf["effects"]), list(defaults["effects"])), (conf["effects"], defaults["effects"])


def _facts(scene) -> dict:
    mesh = scene.mesh
    return {"frame_time": scene.frame_time, "steps_per_frame": scene.steps_per_frame,
            "effects": sorted(scene.effects), "thickness": scene.thickness, "friction": scene.friction,
            "obstacles": [type(o).__name__ for o in scene.obstacles], "handles": len(scene.handles),
            "faces": mesh.n_faces, "nodes": mesh.n_nodes}


@pytest.mark.parametrize("name", SCENE_CONFS)
def test_a_scene_built_from_python_is_the_scene_the_config_runs(name):
    ran = build_simulation(compose_config(f"scene={name}", "mode=nonadaptive", "scale=small"))[0].scene
    built = build_scene(name, ran.material)
    a, b = _facts(built), _facts(ran)
    assert a.keys() == b.keys()
    assert all(_same(a[k], b[k]) for k in a), (a, b)
    assert np.array_equal(built.mesh.face_nodes, ran.mesh.face_nodes)
    assert np.array_equal(built.mesh.node_x, ran.mesh.node_x)  # the same grid and the same seeded jitter
