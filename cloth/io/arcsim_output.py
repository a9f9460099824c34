"""ARCSim's output folder, read for comparison (experiments.compare_arcsim).

``arcsim simulate conf.json OUT`` (Narain, Samii and O'Brien 2012; read from its source,
src/runphysics.cpp and src/io.cpp) writes into OUT:

* ``NNNN_CC.obj``: cloth CC (two digits, from 00) at frame NNNN (four digits). Frame 0000 is
  written once the scene is set up (its initial remesh and relaxation done), before the first time
  step: the initial state. Frame k >= 1 is the state after k frames, at time k x frame_time. Lines:
  ``vt u v`` (material coordinates, m, one per vert), ``v x y z`` (world positions, m, one per
  node), ``f n/t n/t n/t`` (triangles: 1-based node / vert), and ARCSim's own extra lines (``vl``,
  ``ny``, ``nv``, ``nl``, ``e``, ``ea``, ``ed``, ``el``, ``tl``, ``ts``, ``td``), ignored here. No
  frame is written from 10000 on.
* ``timing``: one line per frame from frame 1 (none for frame 0), written when the frame is
  saved; one column per module (TIMING_MODULES, in that order), each the wall time (s, microsecond
  clock) the module took during that frame, not cumulative. Time outside the modules (obstacle
  motion, handles, saving) is in no column. The first line also holds the set-up's remeshing and
  relaxation (the module timers run from the start). ``arcsim resume OUT N`` appends to it: its
  lines then no longer map one to one to frames (:func:`read_timing` says so).
* ``conf.json`` (a copy of the scene: JSON with // comments), ``obs_MM.obj`` (obstacle MM's base
  mesh, once) and ``NNNNobsMM.txt`` (its transform at frame NNNN): not read here but conf.json's
  frame time.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cloth.core.jsonc import strip_json_comments
from cloth.io.obj import read_obj

FRAME_FILE = re.compile(r"(\d{4})_(\d{2})\.obj")  # NNNN_CC.obj: frame, cloth
TIMING_FILE = "timing"
CONF_FILE = "conf.json"
# ARCSim's Simulation::timers, the columns of its timing file (src/simulation.hpp)
TIMING_MODULES = ("proximity", "physics", "strain_limiting", "collision", "remeshing", "separation", "pop_filter",
                  "plasticity")


class ArcsimError(ValueError):
    """An ARCSim output folder or file that cannot be read; the message names it."""


@dataclass
class ArcsimFrame:
    """One frame of one cloth (or of several, concatenated) as ARCSim saved it.

    node_x:     (N, 3) float64, world positions (m), the ``v`` lines
    face_nodes: (F, 3) int64, triangles as node indices (0-based)
    vert_u:     (V, 2) float64, material coordinates (m), the ``vt`` lines
    face_verts: (F, 3) int64, triangles as vert indices (0-based)
    """
    node_x: np.ndarray
    face_nodes: np.ndarray
    vert_u: np.ndarray
    face_verts: np.ndarray

    @property
    def n_faces(self) -> int:
        return int(self.face_nodes.shape[0])


@dataclass
class ArcsimTiming:
    """ARCSim's timing file: ``seconds`` (L, M) float64, row i the frame i + 1, column m the module
    ``modules[m]``; ``note`` says why the rows cannot be taken as frames 1 .. L ('' when they can)."""
    seconds: np.ndarray
    modules: tuple
    note: str = ""

    def frame_seconds(self) -> dict[int, np.ndarray]:
        """frame -> (M,) seconds per module; {} when the note says the rows are not frames."""
        if self.note:
            return {}
        return {i + 1: row for i, row in enumerate(self.seconds)}


def frame_files(out_dir) -> dict[int, dict[int, Path]]:
    """frame -> cloth -> path of every ``NNNN_CC.obj`` in `out_dir` ({} when there is none)."""
    out: dict[int, dict[int, Path]] = {}
    for p in Path(out_dir).iterdir():
        m = FRAME_FILE.fullmatch(p.name)
        if m and p.is_file():
            out.setdefault(int(m.group(1)), {})[int(m.group(2))] = p
    return dict(sorted(out.items()))


def read_cloth_obj(path) -> ArcsimFrame:
    """One ``NNNN_CC.obj`` (polygons, if any, as fans); ArcsimError naming the file for a face
    without material coordinates or an index outside the file's lines."""
    obj = read_obj(path, error=ArcsimError, texcoords=True)
    if not obj.faces:
        raise ArcsimError(f"{path}: has no faces")
    tris = [(p[0], p[j], p[j + 1]) for p in obj.faces for j in range(1, len(p) - 1)]
    if any(c[1] is None for t in tris for c in t):
        raise ArcsimError(f"{path}: a face has no material coordinate (f v/vt): not ARCSim's output?")
    face_nodes = np.array([[c[0] for c in t] for t in tris], dtype=np.int64) - 1
    face_verts = np.array([[c[1] for c in t] for t in tris], dtype=np.int64) - 1
    for name, idx, n in (("v", face_nodes, len(obj.positions)), ("vt", face_verts, len(obj.texcoords))):
        if idx.min() < 0 or idx.max() >= n:
            bad = int(idx.max() if idx.max() >= n else idx.min()) + 1
            raise ArcsimError(f"{path}: a face refers to {name} line {bad} of {n}")
    return ArcsimFrame(node_x=obj.positions, face_nodes=face_nodes, vert_u=obj.texcoords, face_verts=face_verts)


def concatenate(frames: list[ArcsimFrame]) -> ArcsimFrame:
    """Several cloths of one frame as one mesh (indices shifted)."""
    if len(frames) == 1:
        return frames[0]
    n_off = np.cumsum([0] + [f.node_x.shape[0] for f in frames[:-1]])
    v_off = np.cumsum([0] + [f.vert_u.shape[0] for f in frames[:-1]])
    return ArcsimFrame(node_x=np.concatenate([f.node_x for f in frames]),
                       face_nodes=np.concatenate([f.face_nodes + o for f, o in zip(frames, n_off)]),
                       vert_u=np.concatenate([f.vert_u for f in frames]),
                       face_verts=np.concatenate([f.face_verts + o for f, o in zip(frames, v_off)]))


def read_timing(path, last_frame: int | None = None) -> ArcsimTiming:
    """ARCSim's ``timing`` file (see the module docstring). With `last_frame` (the last NNNN of
    the folder), more rows than that is a resumed run's file: the note says so, and no row is
    given to a frame. ArcsimError for a line that is not numbers or rows of unequal length."""
    path = Path(path)
    rows = []
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise ArcsimError(f"{path}: cannot be read ({exc})") from None
    for i, line in enumerate(lines, 1):
        if not line.strip():
            continue
        try:
            rows.append([float(tok) for tok in line.split()])
        except ValueError:
            raise ArcsimError(f"{path}: line {i} is not numbers: {line[:60]!r}") from None
    widths = {len(r) for r in rows}
    if len(widths) > 1:
        raise ArcsimError(f"{path}: its lines have {sorted(widths)} columns, not one count")
    seconds = np.asarray(rows, dtype=np.float64).reshape(len(rows), widths.pop() if widths else 0)
    m = seconds.shape[1]
    modules = TIMING_MODULES if m == len(TIMING_MODULES) else tuple(f"module_{k}" for k in range(m))
    note = ""
    if last_frame is not None and len(rows) > last_frame:
        note = (f"{path.name} has {len(rows)} lines for frames 1-{last_frame}: a resumed run appends to it "
                f"(arcsim resume), so its lines are not frames")
    return ArcsimTiming(seconds=seconds, modules=modules, note=note)


def read_conf(path) -> dict:
    """A scene file of ARCSim (JSON with comments) as a dict; ArcsimError naming it if unreadable."""
    path = Path(path)
    try:
        return json.loads(strip_json_comments(path.read_text()))
    except (OSError, UnicodeDecodeError, ValueError) as exc:
        raise ArcsimError(f"{path}: cannot be read as ARCSim's JSON ({exc})") from None


def conf_frame_time(conf: dict) -> float | None:
    """Seconds per saved frame of an ARCSim scene: ``frame_time``, or ``timestep`` x
    ``save_frames`` (ARCSim's older keys, src/conf.cpp); None when neither is there."""
    if "frame_time" in conf:
        return float(conf["frame_time"])
    if "timestep" in conf:
        return float(conf["timestep"]) * float(conf.get("save_frames", 1))
    return None
