"""Checkpoints pickled before cloth/ was split into subpackages name the flat modules
(cloth.material, cloth.view, ...): the checkpoint loader maps them to today's modules."""

import importlib
import pickle

import pytest
from helpers import COTTON

from cloth.io.checkpoint import MOVED_MODULES, MOVED_NAMES, Checkpoint, CheckpointError, load_checkpoint
from cloth.view.camera import Camera

CAMERA = Camera(position=(0.0, -3.0, 1.0), look_at=(0.0, 0.0, 0.5))


def flat_package_checkpoint(run_dir, obj, new_module: str, old_module: str):
    """A checkpoint folder whose pickle names `old_module` for `obj`'s class, as the flat package
    wrote it (protocols 2 and 3 write a class reference as the text 'module\\nname\\n'). The
    simulation's stand-in is a class of cloth with a frame (what the loader checks of a simulation),
    holding `obj`: a checkpoint may refer only to the project's classes."""
    sim = Checkpoint(sim=obj, rows=[], frame=0, time=0.0)
    data = pickle.dumps({"format": 1, "frame": 0, "time": 0.0, "rows": [], "sim": sim}, protocol=3)
    new, old = f"{new_module}\n".encode(), f"{old_module}\n".encode()
    assert data.count(new) == 1
    path = run_dir / "checkpoint" / "state.pkl"
    path.parent.mkdir(parents=True)
    path.write_bytes(data.replace(new, old))
    return path


@pytest.mark.parametrize("obj,new,old", [(COTTON, "cloth.core.material", "cloth.material"),
                                         (CAMERA, "cloth.view.camera", "cloth.view")])
def test_a_checkpoint_of_the_flat_package_loads(tmp_path, obj, new, old):
    path = flat_package_checkpoint(tmp_path, obj, new, old)
    with pytest.raises((ModuleNotFoundError, AttributeError)):
        pickle.loads(path.read_bytes())  # a plain unpickler does not find the class
    assert load_checkpoint(tmp_path).sim.sim == obj


def test_every_moved_module_and_name_resolves_today():
    for new in MOVED_MODULES.values():
        importlib.import_module(new)
    for (old, name), new in MOVED_NAMES.items():
        assert hasattr(importlib.import_module(new), name), (old, name, new)


def test_an_unreadable_checkpoint_is_named(tmp_path):
    path = flat_package_checkpoint(tmp_path, COTTON, "cloth.core.material", "cloth.no_such_module")
    with pytest.raises(CheckpointError, match="state.pkl: cannot be read"):
        load_checkpoint(tmp_path)
    assert path.is_file()


def test_a_checkpoint_naming_the_stage_plan_in_cloth_simulation_loads(tmp_path):
    """Checkpoints written while the stage plan was defined in cloth.simulation name
    cloth.simulation.Stages: it is defined in cloth.stages now and re-exported there."""
    from cloth.stages import Stages

    plan = Stages(forces=("membrane", "gravity"), remesh=True)
    flat_package_checkpoint(tmp_path, plan, "cloth.stages", "cloth.simulation")
    assert load_checkpoint(tmp_path).sim.sim == plan
