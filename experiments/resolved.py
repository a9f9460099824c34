"""What a run used, read back from the objects its config became (a run folder's resolved.yaml):
config.yaml says what was asked, :func:`resolved_record` what ran.

Apart from :mod:`experiments.build` because it reads built objects and checks nothing; a record of
the values, in plain YAML data, for a reader of the run folder.
"""

from __future__ import annotations

import dataclasses
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from experiments.build import Built


def _record_value(v):
    """A built value as plain YAML data (dataclasses as mappings, tuples and arrays as lists)."""
    if dataclasses.is_dataclass(v) and not isinstance(v, type):
        return {f.name: _record_value(getattr(v, f.name)) for f in dataclasses.fields(v)}
    if isinstance(v, dict):
        return {str(k): _record_value(x) for k, x in v.items()}
    if isinstance(v, (list, tuple, set, frozenset)):
        items = sorted(v) if isinstance(v, (set, frozenset)) else v
        return [_record_value(x) for x in items]
    if isinstance(v, np.ndarray):
        return _record_value(v.tolist())
    if isinstance(v, np.generic):
        return v.item()
    if v is None or isinstance(v, (bool, int, float, str)):
        return v
    return str(v)


def resolved_record(built: Built) -> dict:
    """The values a run uses, read from the built objects (what a run folder's resolved.yaml
    holds): the frames, the scene (its builder's parameters and what the scene became), the
    material, the solver's options, the remesher's (sizing, remesh, pop filter, view), the
    buckling compensation's and max_speed. config.yaml says what was asked; this, what ran (an
    ARCSim conf's remeshing sizes, a scale preset, resolution_factor are applied here)."""
    sim = built.sim
    scene, remesher = sim.scene, sim.remesher
    remesh = None
    if remesher is not None:
        remesh = {"kind": type(remesher).__name__, "every": remesher.every,
                  "sizing": _record_value(remesher.sizing), "remesh": _record_value(remesher.params),
                  "pop_filter": _record_value(remesher.pop)}
        if hasattr(remesher, "view"):
            remesh["view"] = _record_value(remesher.view)
            remesh["frame_time"] = float(remesher.frame_time)
    return {
        "frames": int(built.frames),
        "max_speed": float(sim.max_speed),
        "scene": {"name": scene.name, "params": _record_value(built.scene_params),
                  "frame_time": float(scene.frame_time), "steps_per_frame": int(scene.steps_per_frame),
                  "effects": _record_value(scene.effects), "thickness": float(scene.thickness),
                  "friction": float(scene.friction), "faces": int(sim.mesh.n_faces),
                  "camera": None if scene.camera is None else type(scene.camera).__name__},
        "material": {"kind": type(scene.material).__name__, **_record_value(scene.material)},
        "solver": _record_value(sim.solver),
        "collision": _record_value(sim.collision),
        "remesher": remesh,
        "buckling": _record_value(sim.buckling),
    }
