"""Per-frame states of a run (``states/frame_NNNNN.npz``): what the screen-space accuracy
measures (cloth.eval.screenspace) read back, without re-simulating, and what a restart needs
(:meth:`cloth.simulation.Simulation.restart_from`: the re-synchronised error of
experiments.sync starts every mode from the reference's state).

Format 2 (this code writes it; format 1 files, positions only, are still read): positions in
float64, and with ``restart=True`` everything the cloth's next frames depend on besides the scene
itself (which is a function of time: body, handles' motions, camera): velocities, material
coordinates and topology, pins and the handles' anchors. The solver's warm start is not kept:
a restarted run's iterations start from zero, so it agrees with the uninterrupted run to the
solver's tolerance, not bit for bit.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from cloth.collision.obstacles import CapsuleUnion
from cloth.io.manifest import atomic_write

STATE_FORMAT = 2  # version of the states/frame_NNNNN.npz layout this code writes
READABLE_FORMATS = (1, 2)


class StateError(ValueError):
    """A missing or malformed per-frame state file; the message names the file."""


def save_state(path, mesh, frame: int, time: float, obstacles=(), handles=(), restart: bool = False) -> Path:
    """Write ``states/frame_NNNNN.npz`` atomically (compressed npz) and return its path.

    Keys: ``format`` (STATE_FORMAT), ``frame`` (int), ``time`` (s), ``node_x`` (N, 3) float64 world
    positions (m), ``face_nodes`` (F, 3) int32 triangles as node indices, ``capsule_ends`` (K, 2, 3)
    float32 and ``capsule_radii`` (K,) float32 of every capsule of every capsule-union obstacle (the
    body, spheres, capsules: exact and a few hundred bytes), ``obstacle_x`` (M, 3) float32 and
    ``obstacle_faces`` (L, 3) int32, the display tessellation of every other obstacle (a ground
    plane: two triangles).

    With `restart` (a cloth.core.mesh.Mesh and the scene's `handles`, cloth.core.scene.Handle), also
    the keys of RESTART_KEYS: ``node_v`` (N, 3) float64 m/s, ``node_pinned`` (N,) bool, ``vert_u``
    (V, 2) float64 m, ``vert_node`` (V,) and ``face_verts`` (F, 3) int32, ``node_handle`` (N,)
    int32 (the handle of each node, -1 for none) and ``handle_local`` (N, 3) float64 (a handle
    node's position in its motion's frame, :attr:`Handle.local`; 0 elsewhere).
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
        "node_x": np.asarray(mesh.node_x, dtype=np.float64),
        "face_nodes": np.asarray(mesh.vert_node[mesh.face_verts], dtype=np.int32),
        "capsule_ends": np.concatenate(ends) if ends else np.zeros((0, 2, 3), np.float32),
        "capsule_radii": np.concatenate(radii) if radii else np.zeros(0, np.float32),
        "obstacle_x": np.concatenate(ox) if ox else np.zeros((0, 3), np.float32),
        "obstacle_faces": np.concatenate(of) if of else np.zeros((0, 3), np.int32),
    }
    if restart:
        n = mesh.node_x.shape[0]
        node_handle = np.full(n, -1, dtype=np.int32)
        handle_local = np.zeros((n, 3))
        for i, h in enumerate(handles):
            node_handle[h.nodes] = i
            handle_local[h.nodes] = h.local
        arrays.update(node_v=np.asarray(mesh.node_v, dtype=np.float64), node_pinned=np.asarray(mesh.node_pinned, bool),
                      vert_u=np.asarray(mesh.vert_u, dtype=np.float64),
                      vert_node=np.asarray(mesh.vert_node, dtype=np.int32),
                      face_verts=np.asarray(mesh.face_verts, dtype=np.int32),
                      node_handle=node_handle, handle_local=handle_local)
    with atomic_write(path, durable=False) as tmp, open(tmp, "wb") as fh:  # one per frame: no fsync
        np.savez_compressed(fh, **arrays)
    return path


STATE_KEYS = ("format", "frame", "time", "node_x", "face_nodes", "capsule_ends", "capsule_radii",
              "obstacle_x", "obstacle_faces")
RESTART_KEYS = ("node_v", "node_pinned", "vert_u", "vert_node", "face_verts", "node_handle", "handle_local")


def load_state(path) -> dict:
    """The arrays of a state file (see :func:`save_state`), positions as float64, and ``restart``
    (bool: whether it holds RESTART_KEYS); StateError names a bad file."""
    path = Path(path)
    try:
        with np.load(path) as z:
            missing = [k for k in STATE_KEYS if k not in z.files]
            if missing:
                raise StateError(f"state file {path} lacks {missing}")
            out = {k: z[k] for k in STATE_KEYS}
            out["restart"] = all(k in z.files for k in RESTART_KEYS)
            if out["restart"]:
                out.update({k: z[k] for k in RESTART_KEYS})
    except (OSError, ValueError, EOFError) as exc:
        if isinstance(exc, StateError):
            raise
        raise StateError(f"cannot read state file {path}: {exc}") from None
    if int(out["format"]) not in READABLE_FORMATS:
        raise StateError(f"state file {path} has format {int(out['format'])}, this code reads {READABLE_FORMATS}")
    out["frame"], out["time"] = int(out["frame"]), float(out["time"])
    for k in ("node_x", "capsule_ends", "capsule_radii", "obstacle_x"):
        out[k] = out[k].astype(np.float64)
    for k in ("face_nodes", "obstacle_faces"):
        out[k] = out[k].astype(np.int64)
    n = out["node_x"].shape[0]
    if out["face_nodes"].size and (out["face_nodes"].min() < 0 or out["face_nodes"].max() >= n):
        raise StateError(f"state file {path}: face_nodes index outside its {n} nodes")
    if out["restart"]:
        for k in ("vert_node", "face_verts", "node_handle"):
            out[k] = out[k].astype(np.int64)
        nv = out["vert_u"].shape[0]
        if (out["node_v"].shape != (n, 3) or out["vert_node"].shape != (nv,) or out["node_handle"].shape != (n,)
                or out["handle_local"].shape != (n, 3) or out["face_verts"].shape[0] != out["face_nodes"].shape[0]
                or (out["face_verts"].size and (out["face_verts"].min() < 0 or out["face_verts"].max() >= nv))
                or (nv and (out["vert_node"].min() < 0 or out["vert_node"].max() >= n))):
            raise StateError(f"state file {path}: its restart arrays do not fit its {n} nodes and {nv} verts")
    return out


def require_restart(state: dict, path) -> dict:
    """`state` if it holds what a restart needs (RESTART_KEYS); StateError naming `path` otherwise."""
    if not state.get("restart"):
        raise StateError(f"state file {path} holds positions only (written without restart data, or format 1): "
                         f"run the reference again with this code (its states carry velocities and material "
                         f"coordinates)")
    return state


def merge_states(states: list) -> dict:
    """One state from several (the characters of a crowd under one camera): meshes concatenated."""
    if len(states) == 1:
        return states[0]
    out = {k: v for k, v in states[0].items() if k not in RESTART_KEYS}
    out["restart"] = False  # a crowd's merged image state: each character restarts from its own
    for xk, fk in (("node_x", "face_nodes"), ("obstacle_x", "obstacle_faces")):
        offs = np.cumsum([0] + [s[xk].shape[0] for s in states[:-1]])
        out[xk] = np.concatenate([s[xk] for s in states])
        out[fk] = np.concatenate([s[fk] + o for s, o in zip(states, offs)])
    out["capsule_ends"] = np.concatenate([s["capsule_ends"] for s in states])
    out["capsule_radii"] = np.concatenate([s["capsule_radii"] for s in states])
    return out
