"""The frame loop: sizing and remeshing (adaptive modes), then N implicit steps with contact.

One frame, as in DESIGN.md section 1::

    remesh stage (mode hook; absent in mode=nonadaptive)
    for each of the frame's steps:
        handles -> prescribed positions at t + h
        implicit Euler step (force terms of the declared effects, linear solve)
        obstacle contact (only if the scene declares 'obstacles')
        self-collision: proximity, CCD, impact zones (only if it declares 'self_collision'), in
            one pass with the cloth against triangle-mesh obstacles (only if it has some)
    per-frame record

After a remesh that changed the mesh, a scene with 'self_collision' is untangled (crossings
removed by intersection contour minimisation, cloth.untangle) before the steps.

The three modes share all of this; only the remesh stage (its sizing field) differs.
"""

from __future__ import annotations

import time
import numpy as np

from .adaptive import REMESH_RECORD
from .viewdep import VIEW_RECORD
from .assembly import SparsityPattern
from .forces import Bending, ForceTerm, Gravity, Membrane, Wind, element_families
from .integrator import ContactConstraints, implicit_euler_step
from .linsolve import SolverOptions
from .scene import Scene

# Phases timed in every frame record (seconds of wall time, column time_<phase>_s).
PHASES = ("sizing", "remesh", "physics", "solve", "collisions", "io", "other")
# A free node within (1 + CONTACT_BAND) x thickness of an obstacle at the start of a step is a
# contact candidate for the solve (projection leaves resting nodes at exactly the thickness).
CONTACT_BAND = 0.5
# Columns of the self-collision record; zero in scenes without the effect.
COLLISION_RECORD = {"self_velocity_clamped": 0, "self_proximity": 0, "self_ccd_hits": 0, "self_ccd_passes": 0,
                    "impact_zones": 0, "impact_zone_rounds": 0, "self_collisions_left": 0,
                    "obstacle_proximity": 0, "obstacle_ccd_hits": 0, "obstacle_collisions_left": 0,
                    "intersections_found": 0,
                    "untangle_iterations": 0, "intersections_left": 0, "intersection_depth_m": 0.0,
                    "intersection_length_m": 0.0}
# Bound of the contour-minimisation iterations after a remesh (the record says what is left).
UNTANGLE_ITERATIONS = 30


class SimulationDiverged(RuntimeError):
    """The state became non-finite or a node exceeded the speed limit."""


def build_force_terms(scene: Scene) -> list[ForceTerm]:
    """The force terms of the scene's declared effects, in a fixed order (built once)."""
    terms: list[ForceTerm] = []
    mu, lam = scene.material.lame()
    if "membrane" in scene.effects:
        terms.append(Membrane(mu, lam))
    if "bending" in scene.effects:
        terms.append(Bending(scene.material.bending_stiffness))
    if "gravity" in scene.effects:
        terms.append(Gravity(scene.gravity))
    if "wind" in scene.effects:
        w = scene.wind
        terms.append(Wind(w.velocity, w.drag, w.gust_amplitude, w.gust_frequency))
    return terms


class Remesher:
    """Interface of the remesh stage (cloth.adaptive.AdaptiveRemesher implements it).

    `remesh(sim, timings, stats)` may replace `sim.scene.mesh`; when it does, it calls
    `sim.rebuild()` (masses, rest data, sparsity: only then) and returns True. It adds its
    wall time to timings['sizing'] and timings['remesh'] and its counters to `stats`.
    """

    def remesh(self, sim: "Simulation", timings: dict, stats: dict) -> bool:  # pragma: no cover - interface
        raise NotImplementedError


class Simulation:
    def __init__(self, scene: Scene, solver: SolverOptions | None = None,
                 remesher: Remesher | None = None, max_speed: float = 100.0, buckling=None):
        """`buckling` (cloth.buckling.BucklingParams or None): buckling compensation on the faces
        outside the camera's frustum; needs `scene.camera` (a cloth.camera.CameraPath)."""
        if not max_speed > 0:
            raise ValueError(f"max_speed must be > 0, got {max_speed}")
        if buckling is not None and scene.camera is None:
            raise ValueError("buckling compensation acts on out-of-frustum faces: it needs a camera")
        self.scene = scene
        self.buckling = buckling
        self.solver = solver or SolverOptions()
        self.remesher = remesher
        self.max_speed = float(max_speed)  # m/s: a faster node means the run has gone bad
        self.terms = build_force_terms(scene)
        self.damping = ("damping" in scene.effects)
        self.contact = None
        if "obstacles" in scene.effects:
            from .contact import resolve_obstacle_contacts
            from .obstacles import ObstacleSet
            self.obstacle_set = ObstacleSet(scene.obstacles)
            self.contact = resolve_obstacle_contacts
        self.mesh_obstacles = []  # the triangle-mesh obstacles among them (collided per step, untangled against)
        if self.contact is not None:
            from .meshobstacle import TriangleMeshObstacle
            self.mesh_obstacles = [o for o in self.obstacle_set.obstacles if isinstance(o, TriangleMeshObstacle)]
        self.has_mesh_obstacles = bool(self.mesh_obstacles)
        self.self_collision = None
        if "self_collision" in scene.effects:
            from .selfcollision import SelfCollisionParams
            self.self_collision = SelfCollisionParams(thickness=scene.thickness, friction=scene.friction)
        # Cloth against triangle-mesh obstacles in every step: proximity, CCD and impact zones with
        # the obstacles' vertices as pinned nodes (cloth.selfcollision.resolve_collisions_with_obstacles;
        # with self_collision, one pass for both). None: node-based contact only.
        self.mesh_collision = None
        if self.has_mesh_obstacles and scene.thickness > 0:
            from .selfcollision import SelfCollisionParams
            self.mesh_collision = self.self_collision or SelfCollisionParams(thickness=scene.thickness,
                                                                             friction=scene.friction)
        self._inside_at_start = None  # free nodes inside an obstacle at the step's start (mesh_collision skips them)
        self.frame = 0
        self.time = 0.0
        self.steps_taken = 0
        self.intersections_pending = 0  # crossings the last untangling left (it runs again next frame)
        self.last_energy: dict = {}
        self.rebuild()
        if self.contact is not None:
            self.obstacle_set.set_time(0.0)

    @property
    def mesh(self):
        return self.scene.mesh

    def rebuild(self) -> None:
        """Refresh everything that depends on topology or rest state (after a remesh only)."""
        mesh = self.scene.mesh
        mesh.update_rest_data(self.scene.material.density)
        self.pattern = SparsityPattern(mesh.n_nodes, element_families(mesh, self.terms))
        self.last_dv = None  # warm start of the solver; its size changes with the node count
        for term in self.terms:
            term.rebuild(mesh, self.pattern)
        self.update_buckling()

    def update_buckling(self) -> None:
        """Compression factors (paper eq 11) of the faces out of the frustum of the camera now."""
        if self.buckling is None:
            return
        from .buckling import face_alpha
        mesh = self.scene.mesh
        camera = self.scene.camera.camera_at(self.time)
        out = camera.distance_to_frustum(mesh.node_x[mesh.face_nodes].mean(axis=1)) > 0
        alpha = face_alpha(mesh.face_area, out, self.buckling)
        for term in self.terms:
            if term.name == "membrane":
                term.alpha = alpha
        self.faces_compensated = int(np.count_nonzero(alpha < 1.0))

    # ------------------------------------------------------------------------------------
    def _fixed_targets(self, t: float) -> np.ndarray | None:
        if not self.scene.handles:
            return None
        x = self.mesh.node_x.copy()
        for handle in self.scene.handles:
            x[handle.nodes] = handle.targets(t)
        return x

    def _contact_constraints(self) -> ContactConstraints | None:
        """Free nodes near an obstacle now, with the nearest obstacle's normal and velocity."""
        mesh, scene = self.scene.mesh, self.scene
        free = np.flatnonzero(~mesh.node_pinned)
        phi, normal, vel = self.obstacle_set.query(mesh.node_x[free])
        near = np.flatnonzero(phi < scene.thickness * (1.0 + CONTACT_BAND))
        self._inside_at_start = free[phi < 0.0]
        return ContactConstraints(free[near], np.ascontiguousarray(normal[near]),
                                  np.ascontiguousarray(vel[near]), scene.friction)

    def step(self, timings: dict, stats: dict) -> None:
        scene, mesh, h = self.scene, self.scene.mesh, self.scene.dt
        m = scene.material
        contacts = None
        x_start = mesh.node_x.copy() if self.self_collision is not None or self.mesh_collision is not None else None
        y_start = self._mesh_obstacle_positions() if self.mesh_collision is not None else None
        if self.contact is not None:
            t0 = time.perf_counter()
            contacts = self._contact_constraints()
            timings["collisions"] += time.perf_counter() - t0
        s, self.last_dv = implicit_euler_step(
            mesh, self.terms, self.pattern, h, self.time,
            m.damping_mass if self.damping else 0.0,
            m.damping_stiffness if self.damping else 0.0,
            self._fixed_targets(self.time + h), self.solver, self.last_dv, contacts,
        )
        self.steps_taken += 1
        # frame start + steps within it: no round-off drift over long runs, so that a frame's
        # time is exactly frame * frame_time (camera cuts and keyframes are given at such times)
        k = self.steps_taken - self.frame * scene.steps_per_frame
        self.time = (self.frame + 1) * scene.frame_time if k == scene.steps_per_frame else self.frame * scene.frame_time + k * h
        timings["physics"] += s.time_physics_s
        timings["solve"] += s.time_solve_s
        stats["solver_iterations"] += s.iterations
        stats["solver_iterations_max"] = max(stats["solver_iterations_max"], s.iterations)
        stats["solver_residual"] = max(stats["solver_residual"], s.residual)
        self.last_energy = s.energy
        if self.contact is not None:
            t0 = time.perf_counter()
            self.obstacle_set.set_time(self.time)
            c = self.contact(mesh.node_x, mesh.node_v, mesh.node_pinned, self.obstacle_set,
                             scene.thickness, scene.friction, h)
            stats["contacts"] = max(stats["contacts"], int(c.get("contacts", 0)))
            timings["collisions"] += time.perf_counter() - t0
        if self.mesh_collision is not None:  # cloth-obstacle (and cloth-cloth) collisions in one pass
            t0 = time.perf_counter()
            self._resolve_self_collisions(x_start, h, stats, y_start)
            timings["collisions"] += time.perf_counter() - t0
        elif self.self_collision is not None:
            t0 = time.perf_counter()
            self._resolve_self_collisions(x_start, h, stats)
            timings["collisions"] += time.perf_counter() - t0
        self._check(stats)

    def _mesh_obstacle_positions(self) -> list:
        """Vertex positions (copies) of the triangle-mesh obstacles at the current time."""
        for ob in self.mesh_obstacles:
            ob.set_time(self.time)  # a no-op unless the obstacles were moved since the last step
        return [ob.positions.copy() for ob in self.mesh_obstacles]

    def _resolve_self_collisions(self, x_start: np.ndarray, h: float, stats: dict, y_start=None) -> None:
        """Self-collision response of the step; with y_start (the mesh obstacles' positions at the
        step's start) cloth-obstacle collisions too, in the same pass (cloth-cloth pairs only in
        scenes with self_collision)."""
        from .selfcollision import resolve_collisions_with_obstacles, resolve_self_collisions
        mesh = self.scene.mesh
        x_end = mesh.node_x.copy()
        v_max = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v)))) if len(mesh.node_v) else 0.0
        if y_start is None:
            params = self.self_collision
            s = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x_start,
                                        mesh.node_x, mesh.node_m, mesh.node_pinned, params)
        else:
            params = self.mesh_collision
            obstacles = [(y0, ob.positions, *ob.collision_topology()) for y0, ob in zip(y_start, self.mesh_obstacles)]
            for y0, y1, *_ in obstacles:  # the guard's bound: the obstacles push at their own speed
                v_max = max(v_max, float(np.sqrt(np.max(np.einsum("ij,ij->i", y1 - y0, y1 - y0)))) / h)
            skip = None
            if self._inside_at_start is not None and self._inside_at_start.size:
                skip = np.zeros(mesh.n_nodes, dtype=bool)
                skip[self._inside_at_start] = True
            s = resolve_collisions_with_obstacles(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x_start,
                                                  mesh.node_x, mesh.node_m, mesh.node_pinned, params, obstacles,
                                                  self_pairs=self.self_collision is not None, skip=skip)
            for key in ("obstacle_proximity", "obstacle_ccd_hits"):
                stats[key] = max(stats.get(key, 0), s[key])
            stats["obstacle_collisions_left"] = max(stats["obstacle_collisions_left"], s["obstacle_collisions_left"])
        mesh.node_v += (mesh.node_x - x_end) / h
        # Energy guard. An inelastic response cannot make a node faster than the fastest node
        # was before it, plus the speed of a push across the whole thickness in one step; chains
        # of Gauss-Seidel corrections in dense piles can, and such a node would fly off. Its
        # speed is clamped to that bound (its corrected position stays) and the record counts it.
        cap = v_max + params.thickness / h
        speed = np.sqrt(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))
        over = speed > cap
        if over.any():
            mesh.node_v[over] *= (cap / speed[over])[:, None]
        stats["self_velocity_clamped"] = max(stats["self_velocity_clamped"], int(over.sum()))
        for key in ("self_proximity", "self_ccd_hits", "self_ccd_passes", "impact_zones", "impact_zone_rounds"):
            stats[key] = max(stats[key], s[key])
        # what the frame's worst step left (a later step may clear it; the record keeps the worst)
        stats["self_collisions_left"] = max(stats["self_collisions_left"], s["self_collisions_left"])

    def _mesh_obstacles(self) -> list:
        """(positions, faces) of the triangle-mesh obstacles now (cloth.meshobstacle), [] if none."""
        if not self.mesh_obstacles:
            return []
        self.obstacle_set.set_time(self.time)
        return [ob.triangles() for ob in self.mesh_obstacles]

    def untangle(self, stats: dict) -> None:
        """Remove crossings of the cloth with itself (with 'self_collision') and with triangle-mesh
        obstacles (after a remesh); only the cloth moves. Counts into `stats`."""
        from .untangle import untangle
        mesh = self.scene.mesh
        s = untangle(mesh.face_nodes, mesh.node_x, mesh.node_m, mesh.node_pinned, self.scene.thickness,
                     UNTANGLE_ITERATIONS, obstacles=self._mesh_obstacles())
        stats.update(s)
        self.intersections_pending = int(s["intersections_left"])

    def _check(self, stats: dict) -> None:
        mesh = self.scene.mesh
        frame = self.frame + 1
        if not (np.all(np.isfinite(mesh.node_x)) and np.all(np.isfinite(mesh.node_v))):
            raise SimulationDiverged(f"frame {frame}: non-finite node positions or velocities at t = {self.time:.4f} s")
        speed = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))))
        if speed > self.max_speed:
            raise SimulationDiverged(
                f"frame {frame}: node speed {speed:.3g} m/s exceeds max_speed = {self.max_speed:g} m/s "
                f"at t = {self.time:.4f} s")

    def advance_frame(self) -> dict:
        """Simulate one frame; return its record (one row of frames.parquet, without I/O time)."""
        t_start = time.perf_counter()
        timings = {p: 0.0 for p in PHASES}
        stats = {"solver_iterations": 0, "solver_iterations_max": 0, "solver_residual": 0.0, "contacts": 0}
        stats.update(REMESH_RECORD)
        stats.update(VIEW_RECORD)
        stats.update(COLLISION_RECORD)
        if self.remesher is not None:
            changed = self.remesher.remesh(self, timings, stats)
            # untangle after a remesh that changed the mesh, and in every frame after one that
            # left crossings (the record then says what is still left, not 0)
            pending = getattr(self, "intersections_pending", 0) > 0
            if (changed or pending) and (self.self_collision is not None or self.has_mesh_obstacles):
                t0 = time.perf_counter()
                self.untangle(stats)
                timings["collisions"] += time.perf_counter() - t0
        if self.buckling is not None:
            t0 = time.perf_counter()
            self.update_buckling()
            timings["sizing"] += time.perf_counter() - t0
        for _ in range(self.scene.steps_per_frame):
            self.step(timings, stats)
        self.frame += 1
        record = self.state_record()
        record.update(stats)
        wall = time.perf_counter() - t_start
        for p in PHASES:
            record[f"time_{p}_s"] = timings[p]
        record["time_other_s"] = max(wall - sum(timings[p] for p in PHASES if p != "other"), 0.0)
        record["wall_s"] = wall
        return record

    def view_counts(self) -> dict:
        """Faces in view (in the frustum and facing the camera), back-facing in frame, out of frame.

        NaN without a camera. The same definitions as the view-dependent sizing (face centroids).
        """
        nan = float("nan")
        if self.scene.camera is None:
            return {"faces_in_view": nan, "faces_back_facing": nan, "faces_out_of_frame": nan,
                    "faces_compensated": nan}
        from .view import face_view_data
        from .viewdep import face_geometry
        c, n = face_geometry(self.scene.mesh)
        d, front = face_view_data(self.scene.camera.camera_at(self.time), c, n)
        inside = d == 0
        return {"faces_in_view": int(np.count_nonzero(inside & front)),
                "faces_back_facing": int(np.count_nonzero(inside & ~front)),
                "faces_out_of_frame": int(np.count_nonzero(~inside)),
                "faces_compensated": self.faces_compensated if self.buckling is not None else 0}

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
        }
