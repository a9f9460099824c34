"""The per-frame record of the frame loop (cloth.simulation): counts, energies and quality of the
current state (:meth:`FrameRecord.state_record`), with the faces in and out of view and the
compressive energy out of view; the frame loop adds its timings and its stages' counters to it
(one row of frames.parquet).

A mixin of :class:`cloth.simulation.Simulation`, not functions taking the simulation: the record
reads the simulation's state (its mesh, time, last step's energy, buckling counters, the scene's
camera and probes), and the runner and the tests call it as ``sim.state_record()``. The class
pickled in checkpoints stays ``cloth.simulation.Simulation``; a mixin has no state of its own, so
no instance of a new class is pickled.
"""

from __future__ import annotations

import numpy as np

from cloth.core.measured import MeasuredMaterial
from cloth.physics.buckling import compressive_energy
from cloth.physics.measured_membrane import measured_compressive_energy
from cloth.view.factors import face_geometry, face_view_data
from cloth.view.paths import rig_paths


class FrameRecord:
    """The per-frame record (:meth:`state_record`). Part of :class:`cloth.simulation.Simulation`
    (module docstring)."""

    def view_counts(self) -> dict:
        """Faces in view (in the frustum and facing the camera), back-facing in frame, out of frame,
        and compressive_energy_out_j (cloth.physics.buckling.compressive_energy of the faces out
        of the frame). NaN without a camera. The same definitions as the view-dependent sizing
        (face centroids). With several cameras (a CameraRig): in view of any, in no camera's
        frame, and faces_in_view_<name> per camera."""
        nan = float("nan")
        if self.scene.camera is None:
            return {"faces_in_view": nan, "faces_back_facing": nan, "faces_out_of_frame": nan,
                    "faces_compensated": nan, "compressive_energy_out_j": nan}
        c, n = face_geometry(self.scene.mesh)
        paths = rig_paths(self.scene.camera)
        inside = np.zeros(len(c), dtype=bool)
        seen = np.zeros(len(c), dtype=bool)
        per_camera = {}
        for name, path in paths:  # several cameras (a CameraRig): in view or frame of any of them
            d, front = face_view_data(path.camera_at(self.time), c, n)
            inside |= d == 0
            seen |= (d == 0) & front
            if len(paths) > 1:
                per_camera[f"faces_in_view_{name}"] = int(np.count_nonzero((d == 0) & front))
        return {"faces_in_view": int(np.count_nonzero(seen)),
                "faces_back_facing": int(np.count_nonzero(inside & ~seen)),
                "faces_out_of_frame": int(np.count_nonzero(~inside)),
                "faces_compensated": self.faces_compensated if self.buckling is not None else 0,
                "compressive_energy_out_j": self.compressive_energy(np.flatnonzero(~inside)), **per_camera}

    def compressive_energy(self, faces: np.ndarray) -> float:
        """J: the membrane energy of the compressive principal strains of `faces` (what buckling
        compensation removes), for either material type."""
        mesh, material = self.scene.mesh, self.scene.material
        if isinstance(material, MeasuredMaterial):
            return float(measured_compressive_energy(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area,
                                                     material.stretching_samples, np.asarray(faces, dtype=np.int64)))
        mu, lam = material.lame()
        return compressive_energy(mesh, mu, lam, faces)

    def state_record(self) -> dict:
        """Counts, energies and quality of the current state."""
        mesh = self.scene.mesh
        v2 = np.einsum("ij,ij->i", mesh.node_v, mesh.node_v)
        energy = self.last_energy  # evaluated at the start of the last step: no extra assembly
        view = self.view_counts()
        return {**view,
            "frame": self.frame,
            "sim_time_s": self.time,
            "nodes": mesh.n_nodes,
            "verts": mesh.n_verts,
            "faces": mesh.n_faces,
            "kinetic_energy_j": float(0.5 * np.sum(mesh.node_m * v2)),
            "potential_energy_j": float(sum(energy.values())),
            "elastic_energy_j": float(energy.get("membrane", 0.0) + energy.get("bending", 0.0)),
            "max_speed_m_s": float(np.sqrt(v2.max())),
            "min_face_quality": float(mesh.face_quality().min()),
            **{k: v for probe in self.scene.probes for k, v in probe(mesh).items()},
        }
