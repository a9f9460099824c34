"""The restart protocol of the frame loop (cloth.simulation): a simulation continues from a saved
state of another run of the same scene (cloth.io.states with restart data), possibly of another
mode or resolution; the re-synchronised error starts every mode from the reference's state.

A mixin of :class:`cloth.simulation.Simulation`, not a function taking the simulation: a restart
resets the frame loop's own counters (frame, time, the step and tick counters, the pending
untangling) and rebuilds its derived data (``rebuild``), and its callers (experiments.sync, the
tests) call it as ``sim.restart_from(state)``. The class pickled in checkpoints stays
``cloth.simulation.Simulation``; a mixin has no state of its own, so no instance of a new class is
pickled.
"""

from __future__ import annotations

import numpy as np

from cloth.core.mesh import Mesh
from cloth.core.transfer import transfer_node_values
from cloth.stepcontrol import MAX_STEP_HALVINGS


def _handle_ids(state: dict, n_handles: int, what: str) -> np.ndarray:
    """The state's node_handle (N,); ValueError when it names more handles than the scene has."""
    ids = np.asarray(state["node_handle"])
    if ids.size and int(ids.max()) >= n_handles:
        raise ValueError(f"{what} has {int(ids.max()) + 1} handles, this scene {n_handles}")
    return ids


def _mesh_of(topology: dict, node_x, node_v, density: float) -> Mesh:
    """A Mesh with a state's topology (material coordinates, verts, faces, pins) at `node_x`, `node_v`."""
    return Mesh(node_x=np.array(node_x, dtype=np.float64), node_v=np.array(node_v, dtype=np.float64),
                node_pinned=np.array(topology["node_pinned"], dtype=bool),
                vert_u=np.array(topology["vert_u"], dtype=np.float64),
                vert_node=topology["vert_node"], face_verts=topology["face_verts"], density=density)


class Restart:
    """The restart protocol (:meth:`restart_from`). Part of :class:`cloth.simulation.Simulation`
    (module docstring)."""

    def restart_from(self, state: dict, own_mesh: dict | None = None) -> None:
        """Continue from a saved state of a run of the same scene (cloth.io.states with restart data,
        possibly of another mode or resolution) at its frame: the re-synchronised error starts
        every mode from the reference's state.

        `own_mesh` (a state of this mode's own run at the same frame, with restart data): a
        remeshing mode then restarts on that mesh (its topology, material coordinates, pins and
        handle nodes) with positions and velocities transferred from `state` by material
        coordinates, exactly as a fixed mesh takes them on its own mesh, so that every mode starts
        from its own mesh at the same distance from the truth (the symmetric restart). Without it:

        The scene's time-dependent parts (body, handles' motions, camera) are functions of time
        and are set to the state's time. The cloth: a remeshing mode takes the state's mesh as it
        is (its topology, material coordinates, positions, velocities, pins and handle anchors)
        and remeshes it with its own sizing on the next frame; a fixed mesh keeps its own
        topology and takes positions and velocities interpolated at its nodes' material points
        (cloth.core.transfer), its handle nodes placed on their own motions. The solver's warm
        start and the crossings pending from an earlier untangling start afresh. ValueError
        names a state that does not fit (another frame time, other handles).
        """
        scene = self.scene
        frame = int(state["frame"])
        t = frame * scene.frame_time
        if not abs(t - float(state["time"])) <= 1e-9 * max(1.0, abs(t)):
            raise ValueError(f"state of frame {frame} is at t = {state['time']} s, but frame {frame} of this "
                             f"scene is at {t} s (another frame time)")
        handle_ids = _handle_ids(state, len(scene.handles), "the state")
        if self.remesher is not None and own_mesh is not None:
            if int(own_mesh["frame"]) != frame:
                raise ValueError(f"own_mesh is a state of frame {int(own_mesh['frame'])}, the state of frame {frame}")
            own_handles = _handle_ids(own_mesh, len(scene.handles), "own_mesh")
            values, _ = transfer_node_values(state, own_mesh["vert_u"], own_mesh["vert_node"], own_mesh["face_verts"])
            scene.mesh = _mesh_of(own_mesh, values["node_x"], values["node_v"], scene.material.density)
            for i, h in enumerate(scene.handles):
                h.nodes = np.flatnonzero(own_handles == i)
                self._restore_fixed_handle(h, h.nodes, own_mesh["handle_local"], t)
        elif self.remesher is not None:
            scene.mesh = _mesh_of(state, state["node_x"], state["node_v"], scene.material.density)
            for i, h in enumerate(scene.handles):
                h.nodes = np.flatnonzero(handle_ids == i)
                h.local = np.array(state["handle_local"][h.nodes], dtype=np.float64)
                h.restore(t)
        else:
            mesh = scene.mesh
            values, _ = transfer_node_values(state, mesh.vert_u, mesh.vert_node, mesh.face_verts)
            mesh.node_x[:] = values["node_x"]
            mesh.node_v[:] = values["node_v"]
            for i, h in enumerate(scene.handles):
                self._restore_fixed_handle(h, np.flatnonzero(handle_ids == i), state["handle_local"], t)
        self.frame, self.time = frame, t
        self.steps_taken = frame * scene.steps_per_frame  # as if every frame took the scene's steps
        self.dt, self._substep = scene.dt, 0
        self._frame_dt, self._ticks, self._step_ticks = scene.dt, 0, 2 ** MAX_STEP_HALVINGS
        self.intersections_pending = 0
        self.untangle_due = True  # the state may cross (another run's, transferred to this mesh)
        self._inside_at_start = None
        self.node_passing = np.zeros(scene.mesh.n_nodes, dtype=bool)
        self.rebuild()
        if self.stages.obstacle_contact:
            self.obstacle_set.set_time(t)
            for ob in self.mesh_obstacles:
                ob.set_time(t)

    def _restore_fixed_handle(self, h, state_nodes: np.ndarray, state_local: np.ndarray, t: float) -> None:
        """A fixed mesh's handle at resumed time t: its phase, its anchor (the state's when the state
        holds the same nodes, else taken where the nodes are now) and its nodes' pins and positions."""
        mesh = self.scene.mesh
        h.restore(t)
        if h.state == "released":
            mesh.node_pinned[h.nodes] = False
            h.nodes, h.local = np.zeros(0, dtype=np.int64), np.zeros((0, 3))
            return
        mesh.node_pinned[h.nodes] = h.pinned
        if h.state == "waiting":
            return
        if np.array_equal(state_nodes, h.nodes):
            h.local = np.array(state_local[h.nodes], dtype=np.float64)
        else:
            h.attach(mesh.node_x, t)
        if h.pinned:
            mesh.node_x[h.nodes] = h.targets(t)
