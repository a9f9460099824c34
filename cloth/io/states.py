"""Per-frame states of a run (``states/frame_NNNNN.npz``): what the screen-space accuracy
measures (cloth.eval.screenspace) read back, without re-simulating.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cloth.collision.obstacles import CapsuleUnion
from cloth.io.manifest import atomic_write

STATE_FORMAT = 1  # version of the states/frame_NNNNN.npz layout


class StateError(ValueError):
    """A missing or malformed per-frame state file; the message names the file."""


def save_state(path, mesh, frame: int, time: float, obstacles=()) -> Path:
    """Write ``states/frame_NNNNN.npz`` atomically (compressed npz) and return its path.

    Keys: ``format`` (STATE_FORMAT), ``frame`` (int), ``time`` (s), ``node_x`` (N, 3) float32 world
    positions (m), ``face_nodes`` (F, 3) int32 triangles as node indices, ``capsule_ends`` (K, 2, 3)
    float32 and ``capsule_radii`` (K,) float32 of every capsule of every capsule-union obstacle (the
    body, spheres, capsules: exact and a few hundred bytes), ``obstacle_x`` (M, 3) float32 and
    ``obstacle_faces`` (L, 3) int32, the display tessellation of every other obstacle (a ground
    plane: two triangles).
    """
    path = Path(path)
    ends, radii, ox, of = [], [], [], []
    n_ox = 0
    for ob in obstacles:
        if isinstance(ob, CapsuleUnion):
            ends.append(np.asarray(ob.ends, dtype=np.float32).reshape(-1, 2, 3))
            radii.append(np.asarray(ob.radii, dtype=np.float32).reshape(-1))
        else:
            v, f = ob.to_mesh()
            ox.append(np.asarray(v, dtype=np.float32).reshape(-1, 3))
            of.append(np.asarray(f, dtype=np.int32).reshape(-1, 3) + n_ox)
            n_ox += ox[-1].shape[0]
    arrays = {
        "format": np.int32(STATE_FORMAT),
        "frame": np.int64(frame),
        "time": np.float64(time),
        "node_x": np.asarray(mesh.node_x, dtype=np.float32),
        "face_nodes": np.asarray(mesh.vert_node[mesh.face_verts], dtype=np.int32),
        "capsule_ends": np.concatenate(ends) if ends else np.zeros((0, 2, 3), np.float32),
        "capsule_radii": np.concatenate(radii) if radii else np.zeros(0, np.float32),
        "obstacle_x": np.concatenate(ox) if ox else np.zeros((0, 3), np.float32),
        "obstacle_faces": np.concatenate(of) if of else np.zeros((0, 3), np.int32),
    }
    with atomic_write(path) as tmp, open(tmp, "wb") as fh:
        np.savez_compressed(fh, **arrays)
    return path


STATE_KEYS = ("format", "frame", "time", "node_x", "face_nodes", "capsule_ends", "capsule_radii",
              "obstacle_x", "obstacle_faces")


def load_state(path) -> dict:
    """The arrays of a state file (see :func:`save_state`), positions as float64; StateError names a bad file."""
    path = Path(path)
    try:
        with np.load(path) as z:
            missing = [k for k in STATE_KEYS if k not in z.files]
            if missing:
                raise StateError(f"state file {path} lacks {missing}")
            out = {k: z[k] for k in STATE_KEYS}
    except (OSError, ValueError, EOFError) as exc:
        if isinstance(exc, StateError):
            raise
        raise StateError(f"cannot read state file {path}: {exc}") from None
    if int(out["format"]) != STATE_FORMAT:
        raise StateError(f"state file {path} has format {int(out['format'])}, this code reads {STATE_FORMAT}")
    out["frame"], out["time"] = int(out["frame"]), float(out["time"])
    for k in ("node_x", "capsule_ends", "capsule_radii", "obstacle_x"):
        out[k] = out[k].astype(np.float64)
    for k in ("face_nodes", "obstacle_faces"):
        out[k] = out[k].astype(np.int64)
    n = out["node_x"].shape[0]
    if out["face_nodes"].size and (out["face_nodes"].min() < 0 or out["face_nodes"].max() >= n):
        raise StateError(f"state file {path}: face_nodes index outside its {n} nodes")
    return out


def merge_states(states: list) -> dict:
    """One state from several (the characters of a crowd under one camera): meshes concatenated."""
    if len(states) == 1:
        return states[0]
    out = dict(states[0])
    for xk, fk in (("node_x", "face_nodes"), ("obstacle_x", "obstacle_faces")):
        offs = np.cumsum([0] + [s[xk].shape[0] for s in states[:-1]])
        out[xk] = np.concatenate([s[xk] for s in states])
        out[fk] = np.concatenate([s[fk] + o for s, o in zip(states, offs)])
    out["capsule_ends"] = np.concatenate([s["capsule_ends"] for s in states])
    out["capsule_radii"] = np.concatenate([s["capsule_radii"] for s in states])
    return out
