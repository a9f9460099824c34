"""Checkpoints and final states of a run: what a resumed or replayed run is compared against.

A **checkpoint** (``checkpoint/state.pkl`` in the run folder) is the complete simulation state
at a frame boundary: the whole :class:`cloth.simulation.Simulation` pickled (mesh arrays,
velocities, time, frame and step counters, the remesher and its view-dependent state, the
solver's warm start, force-term data, camera path, character, obstacles, handles) together
with the per-frame records written so far. Everything the next frames depend on lives in that
object, so unpickling it, in this process or a new one, continues bit for bit (a test kills a
run and resumes it). Only the latest checkpoint is kept; it is written atomically (temporary
file, fsynced, then renamed, and the folder fsynced), so a kill while writing leaves the previous
one intact; the temporary file a SIGKILL leaves is removed at the run's next start and end. Beside it,
``checkpoint/state.json`` says which frame it holds and which code wrote it. Size: about 3 kB
per face, mostly the force terms' per-element Hessian buffers (3.6 MB for the 1,152-face
sheet_on_sphere at scale=small, 58 MB at 18,432 faces, scale=paper; pickling takes 30 ms).

The **final state** (``final_state.npz``) is written when a run completes: node positions and
velocities, material coordinates and faces in float64, so that a replay can demand identical
positions without unpickling code objects of an older version.

Pickles name the module of every class they hold. Checkpoints written before the package was
split into subpackages (``cloth.mesh``, ``cloth.adaptive``, ...) still load: the unpickler maps
those module names to today's (``MOVED_MODULES``).

A plain pickle runs whatever its file names (``os.system``, ...) and run folders are shared, so
checkpoints are read by an unpickler that finds only what a checkpoint holds (:class:`_Unpickler`):
the project's classes (defined in ``cloth.*``; created without calling them, their state set as
pickle does), the one function a simulation keeps (``ALLOWED_FUNCTIONS``), numpy arrays, dtypes
and scalars (numpy's reconstructors), scipy's CSR matrix (the Cholesky factor's triangle) and the
data builtins slice, complex, set, frozenset and OrderedDict. The list is what the pickles of
every scene in every mode refer to (pickletools: the GLOBAL and STACK_GLOBAL opcodes); only
numpy's reconstructors, dtype and those builtins are ever called. Anything else stops the load
before it is called, with :class:`UnsafeCheckpoint` naming it.
"""

from __future__ import annotations

import enum
import importlib
import pickle
import types
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cloth.io.manifest import atomic_write, code_version, remove_stale_temp_files, write_json_atomic

CHECKPOINT_FORMAT = 1  # bump when the pickled payload's layout changes
CHECKPOINT_DIR = "checkpoint"
CHECKPOINT_FILE = "state.pkl"
CHECKPOINT_INFO = "state.json"  # frame, time and code of the latest checkpoint, for people and tools
FINAL_STATE_FILE = "final_state.npz"
FINAL_STATE_FORMAT = 1


# Modules of the flat package before it was split into subpackages -> where their names live now.
MOVED_MODULES = {
    "cloth.mesh": "cloth.core.mesh", "cloth.material": "cloth.core.material", "cloth.scene": "cloth.core.scene",
    **{f"cloth.{m}": f"cloth.physics.{m}" for m in
       ("membrane", "bending", "buckling", "forces", "assembly", "linsolve", "integrator")},
    **{f"cloth.{m}": f"cloth.remeshing.{m}" for m in ("sizing", "remesh", "popfilter", "adaptive")},
    "cloth.view": "cloth.view.factors", "cloth.camera": "cloth.view.paths", "cloth.viewdep": "cloth.view.viewdep",
    **{f"cloth.{m}": f"cloth.collision.{m}" for m in
       ("bvh", "ccd", "obstacles", "meshobstacle", "contact", "selfcollision", "untangle")},
    "cloth.scenes": "cloth.scenes.registry", "cloth.character": "cloth.scenes.character",
    "cloth.garments": "cloth.scenes.garments", "cloth.screenspace": "cloth.eval.screenspace",
}
# Names that left their module's successor: (old module, name) -> module.
MOVED_NAMES = {
    ("cloth.view", "Camera"): "cloth.view.camera", ("cloth.view", "ViewError"): "cloth.view.camera",
    ("cloth.membrane", "lame_parameters"): "cloth.core.material",
    ("cloth.viewdep", "face_geometry"): "cloth.view.factors",
    ("cloth.meshobstacle", "SkinnedMannequin"): "cloth.scenes.bodies",
}


class CheckpointError(RuntimeError):
    """A checkpoint that is missing, unreadable or of another format; the message says which."""


class UnsafeCheckpoint(CheckpointError):
    """A checkpoint that refers to something a checkpoint never holds (os.system, builtins.eval,
    ...): refused before it is called; `what` names it."""

    def __init__(self, what: str, path=None, verb: str = "refers to"):
        self.what, self.verb = what, verb
        where = f"{path}: " if path is not None else ""
        super().__init__(f"{where}{verb} {what}, which is not allowed (a checkpoint holds only the project's "
                         f"classes, numpy arrays and a few builtins); it was not loaded. Checkpoints written by "
                         f"this project's save_checkpoint never do: do not resume this one, run its config again")


# What a checkpoint may refer to besides the classes defined in cloth.*: (module, name) as found
# (after MOVED_MODULES). A simulation keeps one function (Simulation.contact); the flat package's
# pickles could also name two pure functions that moved (MOVED_NAMES). No other function of cloth.
ALLOWED_FUNCTIONS = {("cloth.collision.contact", "resolve_obstacle_contacts"),
                     ("cloth.core.material", "lame_parameters"), ("cloth.view.factors", "face_geometry")}
# numpy's reconstructors of arrays, scalars and dtypes, as numpy 2 (numpy._core) and 1 (numpy.core) name them
_NUMPY_CALLABLES = {("numpy", "dtype"),
                    *((m, n) for m in ("numpy._core.multiarray", "numpy.core.multiarray")
                      for n in ("_reconstruct", "scalar")),
                    *((m, "_frombuffer") for m in ("numpy._core.numeric", "numpy.core.numeric"))}
# data builtins: slice is in real checkpoints (an ARCSim scene's rigid parts); the others only build values
_DATA_BUILTINS = {("builtins", "slice"), ("builtins", "complex"), ("builtins", "set"), ("builtins", "frozenset"),
                  ("collections", "OrderedDict")}
ALLOWED_CALLABLES = _NUMPY_CALLABLES | _DATA_BUILTINS  # the globals a checkpoint may call (pickle's REDUCE)
ALLOWED_GLOBALS = ALLOWED_CALLABLES | {("numpy", "ndarray"), ("scipy.sparse._csr", "csr_matrix")}


def _is_project_class(obj) -> bool:
    module = getattr(obj, "__module__", None) or ""
    return isinstance(obj, type) and (module == "cloth" or module.startswith("cloth."))


class _Unpickler(pickle._Unpickler):
    """Reads checkpoints of any layout of the package since checkpoint format 1 (MOVED_MODULES),
    finding only what a checkpoint holds (module docstring) and calling only ALLOWED_CALLABLES
    (and enum classes of cloth: a lookup by value). pickle's Python unpickler, whose every opcode
    can be checked (a checkpoint has a few thousand; its arrays are read as whole buffers)."""

    dispatch = dict(pickle._Unpickler.dispatch)

    def __init__(self, file):
        super().__init__(file)
        self._callable: set[int] = set()  # id() of the objects found that may be called

    def find_class(self, module, name):
        if module in MOVED_MODULES:
            module = MOVED_NAMES.get((module, name), MOVED_MODULES[module])
        what = f"{module}.{name}"
        project = module == "cloth" or module.startswith("cloth.")
        if not project and (module, name) not in ALLOWED_GLOBALS:
            raise UnsafeCheckpoint(what)
        if project and any(part.startswith("__") for part in (*module.split("."), *name.split("."))):
            raise UnsafeCheckpoint(what)  # no cloth.__main__, no Simulation.__init__ or __globals__
        obj = importlib.import_module(module)  # a module of cloth, numpy, scipy or the standard library
        for part in name.split("."):
            obj = getattr(obj, part)
        if project:
            if _is_project_class(obj):
                if issubclass(obj, enum.Enum):
                    self._callable.add(id(obj))
            elif not ((module, name) in ALLOWED_FUNCTIONS and isinstance(obj, types.FunctionType)):
                raise UnsafeCheckpoint(what)
        elif (module, name) in ALLOWED_CALLABLES:
            self._callable.add(id(obj))
        return obj

    def _check_call(self, func) -> None:
        if id(func) not in self._callable:
            name = f"{getattr(func, '__module__', '?')}.{getattr(func, '__qualname__', type(func).__name__)}"
            raise UnsafeCheckpoint(name, verb="calls")

    def load_reduce(self):
        self._check_call(self.stack[-2])
        super().load_reduce()

    dispatch[pickle.REDUCE[0]] = load_reduce

    def _instantiate(self, klass, args):  # opcodes INST and OBJ (protocols 0 and 1)
        if args or not isinstance(klass, type) or hasattr(klass, "__getinitargs__"):
            self._check_call(klass)
        super()._instantiate(klass, args)

    def load_newobj(self):  # cls.__new__(cls, *args): a class that find_class found, not called
        if not isinstance(self.stack[-2], type):
            raise UnsafeCheckpoint(repr(self.stack[-2]), verb="makes an instance of")
        super().load_newobj()

    dispatch[pickle.NEWOBJ[0]] = load_newobj

    def load_newobj_ex(self):
        if not isinstance(self.stack[-3], type):
            raise UnsafeCheckpoint(repr(self.stack[-3]), verb="makes an instance of")
        super().load_newobj_ex()

    dispatch[pickle.NEWOBJ_EX[0]] = load_newobj_ex

    def load_build(self):  # the state of an instance; never of a class, function or module
        inst = self.stack[-2]
        if isinstance(inst, (type, types.FunctionType, types.BuiltinFunctionType, types.ModuleType)):
            raise UnsafeCheckpoint(getattr(inst, "__qualname__", repr(inst)), verb="sets the attributes of")
        super().load_build()

    dispatch[pickle.BUILD[0]] = load_build


@dataclass
class Checkpoint:
    sim: object  # cloth.simulation.Simulation at the frame boundary `frame`
    rows: list  # the per-frame records of frames 1..frame (frames.parquet rows), as dicts
    frame: int  # frames completed when it was written
    time: float  # simulated time, s
    code: dict = field(default_factory=dict)  # git commit, dirty flag, versions that wrote it


def checkpoint_path(run_dir) -> Path:
    return Path(run_dir) / CHECKPOINT_DIR / CHECKPOINT_FILE


def save_checkpoint(run_dir, sim, rows: list) -> Path:
    """Write the checkpoint of `sim` (at a frame boundary) and the records so far, atomically.

    Then state.json beside it (frame, time, code): informational, written after the pickle, so
    it may lag it by one checkpoint after a kill; loading reads only the pickle.
    """
    path = checkpoint_path(run_dir)
    info = {"format": CHECKPOINT_FORMAT, "frame": int(sim.frame), "time": float(sim.time), "code": code_version()}
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        pickle.dump({**info, "rows": list(rows), "sim": sim}, f, protocol=pickle.HIGHEST_PROTOCOL)
    write_json_atomic(path.parent / CHECKPOINT_INFO, {**info, "file": CHECKPOINT_FILE, "bytes": path.stat().st_size})
    return path


def load_checkpoint(run_dir) -> Checkpoint:
    """The latest checkpoint of a run folder; CheckpointError names what is wrong."""
    path = checkpoint_path(run_dir)
    if not path.is_file():
        raise CheckpointError(f"{run_dir}: no checkpoint ({CHECKPOINT_DIR}/{CHECKPOINT_FILE} is missing)")
    try:
        with open(path, "rb") as f:
            payload = _Unpickler(f).load()
    except UnsafeCheckpoint as exc:
        raise UnsafeCheckpoint(exc.what, path, exc.verb) from None
    except Exception as exc:  # truncated file, class that no longer exists, ...
        raise CheckpointError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from None
    if not isinstance(payload, dict) or payload.get("format") != CHECKPOINT_FORMAT:
        got = payload.get("format") if isinstance(payload, dict) else type(payload).__name__
        raise CheckpointError(f"{path}: checkpoint format {got!r}, this code reads format {CHECKPOINT_FORMAT}")
    sim, rows = payload["sim"], payload["rows"]
    if sim.frame != payload["frame"] or len(rows) != payload["frame"]:
        raise CheckpointError(f"{path}: inconsistent (frame {payload['frame']}, simulation at frame {sim.frame}, "
                              f"{len(rows)} records)")
    return Checkpoint(sim=sim, rows=rows, frame=int(payload["frame"]), time=float(payload["time"]),
                      code=payload.get("code", {}))


def remove_checkpoint(run_dir) -> None:
    """Delete the checkpoint of a run that no longer needs it (it completed)."""
    path = checkpoint_path(run_dir)
    path.unlink(missing_ok=True)
    (path.parent / CHECKPOINT_INFO).unlink(missing_ok=True)
    remove_stale_temp_files(path.parent)  # of a checkpoint write that a SIGKILL stopped
    try:
        path.parent.rmdir()
    except OSError:  # absent, or holding files of someone else's
        pass


def save_final_state(path, sim) -> Path:
    """``final_state.npz`` (atomic, uncompressed): format, frame, time (s), node_x (N, 3) m and
    node_v (N, 3) m/s float64, vert_u (V, 2) m float64, vert_node (V,), face_verts (F, 3)."""
    mesh = sim.mesh
    path = Path(path)
    with atomic_write(path) as tmp, open(tmp, "wb") as f:
        np.savez(f, format=np.int32(FINAL_STATE_FORMAT), frame=np.int64(sim.frame), time=np.float64(sim.time),
                 node_x=np.asarray(mesh.node_x, np.float64), node_v=np.asarray(mesh.node_v, np.float64),
                 vert_u=np.asarray(mesh.vert_u, np.float64), vert_node=np.asarray(mesh.vert_node),
                 face_verts=np.asarray(mesh.face_verts))
    return path


def load_final_state(path) -> dict:
    """The arrays of a final_state.npz as a dict (CheckpointError if missing or unreadable)."""
    path = Path(path)
    if not path.is_file():
        raise CheckpointError(f"{path}: no such file")
    try:
        with np.load(path) as z:
            return {k: z[k] for k in z.files}
    except Exception as exc:
        raise CheckpointError(f"{path}: cannot be read ({type(exc).__name__}: {exc})") from None
