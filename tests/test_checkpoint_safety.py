"""Checkpoints cannot run code: checkpoint/state.pkl is read by an unpickler that finds only the
project's classes, numpy's reconstructors and a few data builtins (cloth.io.checkpoint), and calls
none of the project's classes. A crafted checkpoint that would create a file when unpickled is
refused, naming what it refers to, and the file is never created; real checkpoints of several
scenes and modes still load and continue bit for bit."""

import builtins
import os
import pathlib
import pickle
import subprocess

import numpy as np
import pytest
from helpers import QUIET, build_sim, compose_config
from omegaconf import OmegaConf

from cloth.io import manifest
from cloth.io.checkpoint import (
    CheckpointError,
    UnsafeCheckpoint,
    checkpoint_path,
    load_checkpoint,
    save_checkpoint,
)
from cloth.io.recorder import RerunRecorder
from experiments import resume as resume_mod


class _Calls:
    """Unpickled, calls func(*args): what a crafted checkpoint holds instead of a simulation."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def _write(run_dir: pathlib.Path, data: bytes) -> pathlib.Path:
    path = checkpoint_path(run_dir)
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_bytes(data)
    return path


def _checkpoint_of(obj) -> bytes:
    """A checkpoint payload as save_checkpoint writes it, with `obj` for the simulation."""
    return pickle.dumps({"format": 1, "frame": 0, "time": 0.0, "rows": [], "sim": obj},
                        protocol=pickle.HIGHEST_PROTOCOL)


def _global_call(module: str, name: str, args: tuple) -> bytes:
    """A protocol-4 pickle that calls module.name(*args) (opcodes GLOBAL, then REDUCE), spelled
    by hand: a pickler writes a global under its own module's name (os.system as posix.system)."""
    return b"\x80\x04c" + f"{module}\n{name}\n".encode() + pickle.dumps(args, protocol=3)[2:-1] + b"R."


def _variants(marker: pathlib.Path) -> dict:
    """Crafted checkpoints, each of which creates `marker` when a plain unpickler loads it."""
    return {
        "os.system": _checkpoint_of(_Calls(os.system, f"touch {marker}")),
        "builtins.eval": _checkpoint_of(_Calls(builtins.eval, f"open({str(marker)!r}, 'w').close()")),
        "builtins.exec": _checkpoint_of(_Calls(builtins.exec, f"open({str(marker)!r}, 'w').close()")),
        "builtins.open": _checkpoint_of(_Calls(builtins.open, str(marker), "w")),
        "subprocess.Popen": _checkpoint_of(_Calls(subprocess.Popen, ["touch", str(marker)])),
        "pathlib.Path.touch": _checkpoint_of(_Calls(pathlib.Path.touch, marker)),
        # a function of the project with a side effect: no function of cloth but the one a
        # simulation keeps is found
        "cloth function": _checkpoint_of(_Calls(manifest.write_text_atomic, str(marker), "x")),
        # a class of the project whose constructor creates a file: found, but never called
        "cloth class called": _checkpoint_of(_Calls(RerunRecorder, str(marker))),
        # names spelled by hand: os.system itself, a module reached through a module of cloth,
        # a class of another package that a module of cloth imported, an attribute of a class
        "os.system by name": _global_call("os", "system", (f"touch {marker}",)),
        "through cloth": _global_call("cloth.io.manifest", "subprocess.Popen", (["touch", str(marker)],)),
        "imported into cloth": _global_call("cloth.io.manifest", "Path.touch", (marker,)),
        "numpy function": _global_call("numpy", "savetxt", (str(marker), np.zeros(1))),
    }


WHAT = {"os.system": "posix.system", "builtins.eval": "builtins.eval", "builtins.exec": "builtins.exec",
        "builtins.open": "io.open", "subprocess.Popen": "subprocess.Popen", "pathlib.Path.touch": "pathlib.Path.touch",
        "cloth function": "cloth.io.manifest.write_text_atomic",
        "cloth class called": "cloth.io.recorder.RerunRecorder",
        "os.system by name": "os.system", "through cloth": "cloth.io.manifest.subprocess.Popen",
        "imported into cloth": "cloth.io.manifest.Path.touch", "numpy function": "numpy.savetxt"}


def test_the_crafted_checkpoints_are_live(tmp_path):
    """What the loader refuses below does create the file with a plain unpickler."""
    for variant in WHAT:
        marker = tmp_path / variant.replace(" ", "_")
        result = pickle.loads(_variants(marker)[variant])
        result = result["sim"] if isinstance(result, dict) else result  # what the call returned
        if isinstance(result, subprocess.Popen):
            result.wait()
        if hasattr(result, "close"):  # the file that open() returned, the recorder
            result.close()
        assert marker.exists(), variant


@pytest.mark.parametrize("variant", sorted(WHAT))
def test_a_crafted_checkpoint_is_refused_and_runs_nothing(tmp_path, variant):
    marker = tmp_path / "created"
    path = _write(tmp_path / "run", _variants(marker)[variant])
    with pytest.raises(UnsafeCheckpoint) as info:
        load_checkpoint(tmp_path / "run")
    verb = "calls" if variant == "cloth class called" else "refers to"
    assert str(info.value).startswith(f"{path}: {verb} {WHAT[variant]}, which is not allowed")
    assert isinstance(info.value, CheckpointError)
    assert not marker.exists()


def _run_folder(run: pathlib.Path) -> pathlib.Path:
    """A run folder as a killed run leaves it (config, no summary); its checkpoint is the test's."""
    run.mkdir(parents=True, exist_ok=True)
    cfg = compose_config("scene=hanging_sheet", "frames=3", "output.checkpoint_every=1", *QUIET)
    (run / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    return run


def test_resume_refuses_an_unsafe_checkpoint_in_one_line(tmp_path, capsys):
    marker = tmp_path / "created"
    run = _run_folder(tmp_path / "run")
    _write(run, _variants(marker)["os.system"])
    assert resume_mod.main([str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"cannot resume: {checkpoint_path(run)}: refers to posix.system, which is not allowed")
    assert len(err.splitlines()) == 1 and "killed before its first checkpoint" not in err
    assert not marker.exists() and not (run / "summary.json").exists()


def test_resume_names_a_missing_checkpoint_as_such_and_only_then(tmp_path, capsys):
    run = _run_folder(tmp_path / "run")
    assert resume_mod.main([str(run), "--no-progress"]) == 2
    assert "killed before its first checkpoint" in capsys.readouterr().err
    sim = build_sim("scene=hanging_sheet")
    save_checkpoint(run, sim, [])
    path = checkpoint_path(run)
    path.write_bytes(path.read_bytes()[:1000])  # cut off
    assert resume_mod.main([str(run), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"cannot resume: {path}: cannot be read") and len(err.splitlines()) == 1
    assert "killed before its first checkpoint" not in err


SCENES = {
    "hanging_sheet nonadaptive": ("scene=hanging_sheet", "mode=nonadaptive"),
    "hanging_sheet adaptive": ("scene=hanging_sheet", "mode=adaptive"),
    "sheet_on_sphere viewdep": ("scene=sheet_on_sphere", "mode=viewdep", "camera=sheet_half"),
    "solo_dancer viewdep": ("scene=solo_dancer", "mode=viewdep"),  # a character; the Cholesky factor
}


@pytest.mark.parametrize("scene", sorted(SCENES))
def test_a_real_checkpoint_loads_and_continues_bit_for_bit(tmp_path, scene):
    """Written after one frame as save_checkpoint writes it (the format of earlier code too), read
    by the safe unpickler: the next frame is that of the simulation that wrote it."""
    sim = build_sim(*SCENES[scene])
    rows = [sim.advance_frame()]
    save_checkpoint(tmp_path, sim, rows)
    ckpt = load_checkpoint(tmp_path)
    assert ckpt.frame == 1 and len(ckpt.rows) == 1
    sim.advance_frame()
    ckpt.sim.advance_frame()
    assert np.array_equal(ckpt.sim.mesh.node_x, sim.mesh.node_x)
    assert np.array_equal(ckpt.sim.mesh.node_v, sim.mesh.node_v)


def test_a_checkpoint_cannot_set_attributes_of_a_class(tmp_path):
    """BUILD on a class would set class attributes for the whole process (a method replaced)."""
    from cloth.simulation import Simulation

    state = pickle.dumps((None, {"advance_frame": None}), protocol=3)[2:-1]
    _write(tmp_path, b"\x80\x04ccloth.simulation\nSimulation\n" + state + b"b.")
    with pytest.raises(UnsafeCheckpoint, match="sets the attributes of Simulation, which is not allowed"):
        load_checkpoint(tmp_path)
    assert callable(Simulation.advance_frame)
