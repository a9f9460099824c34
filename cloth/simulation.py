"""The frame loop: sizing and remeshing (adaptive modes), then N implicit steps with contact.

Which stages a simulation runs is decided once, in one place, :func:`plan_stages`, from what the
scene declares (``scene.effects``) and what the mode asks for (a remesher, buckling
compensation); a stage that is not planned is never called and costs nothing. One frame, as in
DESIGN.md section 1, one named stage per line::

    remesh            mode=adaptive | viewdep    sizing field, remesh, pop filter
    untangle          self_collision or mesh obstacles: in the first frame (the initial or restarted
                      state may cross), after a remesh that changed the mesh, and after a frame
                      whose untangling left crossings
    buckling          mode's buckling (needs a camera): compression factors of eq 11
    steps              the scene's steps_per_frame (fewer for a character wholly out of view,
                       mode=viewdep; more when scene.obstacle_step asks it of a fast obstacle)
    for each of the frame's steps (step control: a step that fails its checks is undone and
    taken again as two of half its length, at most MAX_STEP_HALVINGS times in a row):
        handles            a handle takes hold at its start_time, fades after its end_time, lets go
        obstacle_contact   'obstacles': contact constraints for the solve (start of the step)
        implicit step      force terms of the declared effects, linear solve; handles prescribed
        strain_limiting    'strain_limiting': principal stretches into the material's limits,
                           v += dx / h (ARCSim's order: after physics, before collisions)
        obstacle_contact   'obstacles': projection out of the obstacles (end of the step)
        collisions         self_collision and/or obstacle_ccd (triangle-mesh obstacles, with a
                           thickness), one pass: proximity, CCD, impact zones
        step checks        finite state, no node over max_speed, no jump of the kinetic energy,
                           a collision pass that did not give up (the last accepted at the finest step)
        untangle           when that pass gave up (left collisions): before the next step
    per-frame record

The three modes share all of this; only the remesh stage (its sizing field) differs.

Where each part lives. This module holds the frame loop: :class:`Simulation` (``advance_frame``,
``step`` and the stages it calls, one method each) and the remesh stage's interface
(:class:`Remesher`). The rest is one module per concept, each a part of :class:`Simulation`:

    cloth.stages       the stage plan (Stages, plan_stages) and the force terms of the implicit
                       step (build_force_terms, FORCE_EFFECTS)
    cloth.stepcontrol  step control (the StepControl mixin: a step checked, undone and halved;
                       MAX_STEP_HALVINGS, KE_JUMP_FACTOR, KE_FLOOR_SPEED_M_S, SimulationDiverged)
    cloth.restart      the restart protocol (the Restart mixin: restart_from)
    cloth.framerecord  the per-frame record (the FrameRecord mixin: state_record, view_counts,
                       compressive_energy)

Their public names are re-exported here (``from cloth.simulation import plan_stages`` keeps
working), and :class:`Simulation` stays defined here: checkpoints pickle it as
``cloth.simulation.Simulation``. The stage implementations the frame loop calls (contact,
collisions, untangling, buckling factors, strain limiting) are looked up in this module's
namespace when they are called, so that a test can replace them here.
"""

from __future__ import annotations

import dataclasses
import time

import numpy as np

from cloth.collision.contact import resolve_obstacle_contacts
from cloth.collision.meshobstacle import mesh_obstacle_triangles, mesh_obstacles
from cloth.collision.obstacles import ObstacleSet
from cloth.collision.selfcollision import (
    CollisionOptions,
    SelfCollisionParams,
    resolve_collisions_with_obstacles,
    resolve_self_collisions,
)
from cloth.collision.untangle import untangle
from cloth.core.records import (
    COLLISION_PARTS,
    COLLISION_RECORD,
    PHASES,
    REMESH_RECORD,
    SIM_PHASES,
    STEP_RECORD,
    STRAIN_LIMIT_RECORD,
    VIEW_RECORD,
)
from cloth.core.scene import Scene
from cloth.framerecord import FrameRecord
from cloth.physics.assembly import SparsityPattern
from cloth.physics.buckling import face_alpha
from cloth.physics.forces import element_families
from cloth.physics.integrator import ContactConstraints, implicit_euler_step
from cloth.physics.linsolve import SolverOptions, solve_capped
from cloth.physics.strainlimiting import limit_strain
from cloth.restart import Restart

# Re-exported: the stage plan and step control, defined in their own modules (module docstring).
from cloth.stages import FORCE_EFFECTS as FORCE_EFFECTS
from cloth.stages import Stages as Stages
from cloth.stages import build_force_terms, plan_stages
from cloth.stepcontrol import KE_FLOOR_SPEED_M_S as KE_FLOOR_SPEED_M_S
from cloth.stepcontrol import KE_JUMP_FACTOR as KE_JUMP_FACTOR
from cloth.stepcontrol import MAX_STEP_HALVINGS, StepControl
from cloth.stepcontrol import SimulationDiverged as SimulationDiverged
from cloth.view.paths import cameras_at

# A free node within (1 + CONTACT_BAND) x thickness of an obstacle at the start of a step is a
# contact candidate for the solve (projection leaves resting nodes at exactly the thickness).
CONTACT_BAND = 0.5
# Bound of the contour-minimisation iterations after a remesh (the record says what is left).
UNTANGLE_ITERATIONS = 30
# Obstacle substeps (obstacle_steps) count the vertices within what they and the cloth cover in a
# frame of the cloth's bounding box, plus this many thicknesses: a contact acts from the thickness
# on, and the box of the frame's start misses the cloth's own motion only by its fastest node's
# travel, which the reach already holds; two thicknesses more is room for the curve of the motion.
OBSTACLE_REACH_MARGIN = 2.0


class Remesher:
    """Interface of the remesh stage (cloth.remeshing.adaptive.AdaptiveRemesher implements it).

    `remesh(sim, timings, stats)` may replace `sim.scene.mesh`; when it does, it calls
    `sim.rebuild()` (masses, rest data, sparsity: only then) and returns True. It adds its
    wall time to timings['sizing'] and timings['remesh'] and its counters to `stats`.
    """

    def remesh(self, sim: Simulation, timings: dict, stats: dict) -> bool:  # pragma: no cover - interface
        raise NotImplementedError


class Simulation(StepControl, Restart, FrameRecord):
    """The frame loop (module docstring); step control, the restart protocol and the per-frame
    record are its mixins, each in a module of its own (cloth.stepcontrol, cloth.restart,
    cloth.framerecord)."""

    def __init__(self, scene: Scene, solver: SolverOptions | None = None,
                 remesher: Remesher | None = None, max_speed: float = 100.0, buckling=None,
                 collision: CollisionOptions | None = None):
        """`buckling` (cloth.physics.buckling.BucklingParams or None): buckling compensation on the
        faces outside the camera's frustum; needs `scene.camera` (a cloth.view.paths.CameraPath).
        `collision`: the collision pass's passes and rounds (None: CollisionOptions' defaults)."""
        if not max_speed > 0:
            raise ValueError(f"max_speed must be > 0, got {max_speed}")
        if buckling is not None and scene.camera is None:
            raise ValueError("buckling compensation acts on out-of-frustum faces: it needs a camera")
        self.scene = scene
        self.buckling = buckling
        self.solver = solver or SolverOptions()
        self.remesher = remesher
        self.max_speed = float(max_speed)  # m/s: a faster node means the run has gone bad
        self.stages = plan_stages(scene, remesher, buckling)
        self.terms = build_force_terms(scene, self.solver.bending_hessian, self.solver.membrane_hessian)
        # What the stages use (None when their stage is not planned). The remesh stage reads
        # `contact`, `obstacle_set` and `self_collision` to keep a remesh clear of obstacles and
        # of crossings.
        self.contact = resolve_obstacle_contacts if self.stages.obstacle_contact else None
        self.obstacle_set = ObstacleSet(scene.obstacles) if self.stages.obstacle_contact else None
        self.mesh_obstacles = mesh_obstacles(scene.obstacles) if self.stages.obstacle_contact else []
        self.collision = collision or CollisionOptions()
        passes = dataclasses.asdict(self.collision)
        self_friction = scene.friction if scene.self_friction is None else scene.self_friction
        self.self_collision = (SelfCollisionParams(thickness=scene.thickness, friction=self_friction,
                                                   self_thickness=scene.self_thickness, **passes)
                               if self.stages.self_collision else None)
        self.mesh_collision = (self.self_collision or SelfCollisionParams(thickness=scene.thickness,
                                                                          friction=scene.friction, **passes)
                               if self.stages.obstacle_ccd else None)
        self._inside_at_start = None  # free nodes inside an obstacle at the step's start (obstacle_ccd skips them)
        self._collision_trees = {}  # the mesh obstacles' broad-phase tree, refitted from pass to pass (not saved)
        # (n_nodes,) bool: free nodes a remesh made inside an obstacle, exempt from obstacle contact
        # until they are out of it (the remesher sets it, :meth:`contact_exempt`, PASSING_DEPTH)
        self.node_passing = np.zeros(scene.mesh.n_nodes, dtype=bool)
        self.frame = 0
        self.time = 0.0
        self.steps_taken = 0
        self.dt = scene.dt  # s: the current step (a view-dependent run may take fewer, longer steps out of
        # view; step control halves it for a step taken again)
        self._substep = 0  # steps taken (accepted) in the current frame
        self._frame_dt = scene.dt  # s: this frame's step before any halving
        self._ticks = 0  # the frame's time taken so far, in units of _frame_dt / 2**MAX_STEP_HALVINGS
        self._step_ticks = 2 ** MAX_STEP_HALVINGS  # the current step's length in those units
        self.intersections_pending = 0  # crossings the last untangling left (it runs again next frame)
        self.untangle_due = True  # the start state has not been checked for crossings yet
        self.faces_compensated = 0
        self.last_energy: dict = {}
        self.rebuild()
        if self.stages.obstacle_contact:
            self.obstacle_set.set_time(0.0)

    def __getstate__(self) -> dict:
        """Pickle (checkpoints) without the collision pass's kept tree: a cache, rebuilt on first use."""
        state = self.__dict__.copy()
        state.pop("_collision_trees", None)
        return state

    def __setstate__(self, state: dict) -> None:
        """Unpickle (checkpoints); a checkpoint of code before the stage plan gets its plan here."""
        self.__dict__.update(state)
        self._collision_trees = {}
        if "stages" not in state:
            self.stages = plan_stages(self.scene, self.remesher, self.buckling)
        for name, value in (("faces_compensated", 0), ("intersections_pending", 0), ("untangle_due", False),
                            ("_frame_dt", self.dt), ("_ticks", 0), ("_step_ticks", 2 ** MAX_STEP_HALVINGS)):
            self.__dict__.setdefault(name, value)
        if "node_passing" not in state:  # a checkpoint of code before the exemption: none exempt
            self.node_passing = np.zeros(self.scene.mesh.n_nodes, dtype=bool)

    @property
    def mesh(self):
        return self.scene.mesh

    @property
    def has_mesh_obstacles(self) -> bool:
        return bool(self.mesh_obstacles)

    def rebuild(self) -> None:
        """Refresh everything that depends on topology or rest state (after a remesh only)."""
        mesh = self.scene.mesh
        mesh.update_rest_data(self.scene.material.density)
        self.pattern = SparsityPattern(mesh.n_nodes, element_families(mesh, self.terms))
        self.last_dv = None  # warm start of the solver; its size changes with the node count
        if len(self.node_passing) != mesh.n_nodes:  # another mesh: the remesher carries the flags over
            self.node_passing = np.zeros(mesh.n_nodes, dtype=bool)
        for term in self.terms:
            term.rebuild(mesh, self.pattern)
        if self.stages.buckling:
            self.update_buckling()

    # ---- the frame -------------------------------------------------------------------------
    def advance_frame(self) -> dict:
        """Simulate one frame; return its record (one row of frames.parquet, without I/O time).

        Times: time_<phase>_s per phase (PHASES), sim_s = the sum over SIM_PHASES (simulation
        time, the paper's Time/Frame), wall_s = the whole call (the runner adds its I/O to it)."""
        t_start = time.perf_counter()
        timings = {p: 0.0 for p in PHASES} | {f"collisions_{part}": 0.0 for part in COLLISION_PARTS}
        stats = {"steps": 0, "solver_iterations": 0, "solver_iterations_max": 0, "solver_residual": 0.0,
                 "solves_capped": 0, "contacts": 0, **STEP_RECORD,
                 **REMESH_RECORD, **VIEW_RECORD, **COLLISION_RECORD, **STRAIN_LIMIT_RECORD}
        stages = self.stages
        changed = stages.remesh and self.remesher.remesh(self, timings, stats)
        if stages.untangle and (changed or self.untangle_due or self.intersections_pending > 0):
            # the start state (a fixed mesh made from a coarse garment can cross a body between
            # its nodes), after a remesh that changed the mesh, and in every frame after one that
            # left crossings (the record then says what is still left, not 0)
            self._timed(timings, "collisions.untangle", self.untangle, stats)
        if stages.buckling:
            self._timed(timings, "sizing", self.update_buckling)
        n_steps = self.scene.steps_per_frame if self.remesher is None else self.remesher.steps_for_frame(self)
        if self.scene.obstacle_step is not None and self.mesh_obstacles:
            n_steps = max(n_steps, self.obstacle_steps())
        self._frame_dt = self.scene.frame_time / n_steps
        self._substep, self._ticks = 0, 0
        stats["dt_min_s"] = self._frame_dt
        for _ in range(n_steps):
            self._controlled_step(0, timings, stats)
        self.dt = self._frame_dt
        stats["steps"] = self._substep  # n_steps, and one more for each step taken again as two
        self.frame += 1
        record = self.state_record()
        record.update(stats)
        wall = time.perf_counter() - t_start
        for p in PHASES:
            record[f"time_{p}_s"] = timings[p]
        for part in COLLISION_PARTS:
            record[f"time_collisions_{part}_s"] = timings[f"collisions_{part}"]
        record["time_other_s"] = max(wall - sum(timings[p] for p in PHASES if p != "other"), 0.0)
        record["sim_s"] = sum(timings[p] for p in SIM_PHASES)  # the paper's Time/Frame
        record["wall_s"] = wall
        return record

    def obstacle_steps(self) -> int:
        """Steps this frame needs so that no mesh-obstacle vertex that can reach the cloth moves more
        than scene.obstacle_step x thickness in one step: the fastest such vertex's speed at the
        frame's start, middle and end, times the frame time, over that distance (a contact is then
        found before it is passed).

        A vertex can reach the cloth this frame when its distance to the cloth's bounding box is
        within what it and the cloth's fastest node cover in the frame, plus the thickness
        (OBSTACLE_REACH_MARGIN of it); a fast part of an obstacle far from the cloth (sphere.json's
        ball on its way back, a hand swinging away from a skirt) asks for no substeps."""
        scene = self.scene
        x, v_cloth = self.mesh.node_x, self.mesh.node_v
        lo, hi = x.min(axis=0), x.max(axis=0)
        cloth_reach = float(np.sqrt((v_cloth * v_cloth).sum(axis=1).max())) * scene.frame_time if len(x) else 0.0
        speed = 0.0
        for ob in self.mesh_obstacles:
            for a in (0.0, 0.5, 1.0):
                y, v = ob.state_at(self.time + a * scene.frame_time)
                if not v.size:
                    continue
                vs = np.sqrt((v * v).sum(axis=1))
                gap = np.sqrt((np.maximum(lo - y, 0.0) ** 2 + np.maximum(y - hi, 0.0) ** 2).sum(axis=1))
                near = gap <= vs * scene.frame_time + cloth_reach + OBSTACLE_REACH_MARGIN * scene.thickness
                if near.any():
                    speed = max(speed, float(vs[near].max()))
        return max(int(np.ceil(speed * scene.frame_time / (scene.obstacle_step * scene.thickness))), 1)

    def step(self, timings: dict, stats: dict) -> None:
        """One implicit step of length self.dt with its contact and collision stages (unchecked:
        :meth:`_controlled_step` checks it, and undoes it if it fails)."""
        stages, mesh, h = self.stages, self.scene.mesh, self.dt  # the handles' phases: _controlled_step
        collide = stages.self_collision or stages.obstacle_ccd
        self._step_gave_up = False  # set by resolve_collisions when its pass leaves collisions
        x_start = mesh.node_x.copy() if collide else None
        y_start = self._mesh_obstacle_positions() if stages.obstacle_ccd else None
        contacts = (self._timed(timings, "collisions.contacts", self._contact_constraints)
                    if stages.obstacle_contact else None)
        self._implicit_step(contacts, timings, stats)
        if stages.strain_limiting:
            self._timed(timings, "physics", self.limit_strain, stats)
        if stages.obstacle_contact:
            self._timed(timings, "collisions.projection", self._project_contacts, stats)
        if collide:  # cloth-obstacle (with obstacle_ccd) and cloth-cloth collisions, in one pass
            self._timed(timings, "collisions.pass", self.resolve_collisions, x_start, h, stats, y_start)

    @staticmethod
    def _timed(timings: dict, phase: str, stage, *args):
        """Run `stage(*args)`, adding its wall time to timings[phase] (accumulates into timings).
        A phase "collisions.untangle" adds it to timings["collisions"] and to the part's own
        timings["collisions_untangle"] (COLLISION_PARTS)."""
        t0 = time.perf_counter()
        out = stage(*args)
        dt = time.perf_counter() - t0
        main, _, part = phase.partition(".")
        timings[main] += dt
        if part:
            timings[f"{main}_{part}"] = timings.get(f"{main}_{part}", 0.0) + dt
        return out

    # ---- the stages ------------------------------------------------------------------------
    def update_buckling(self) -> None:
        """Compression factors (paper eq 11) of the faces out of the frustum of the camera now."""
        if self.buckling is None:
            return
        mesh = self.scene.mesh
        centroids = mesh.node_x[mesh.face_nodes].mean(axis=1)
        out = np.ones(mesh.n_faces, dtype=bool)  # out of every camera's frustum (several: a CameraRig)
        for camera in cameras_at(self.scene.camera, self.time):
            out &= camera.distance_to_frustum(centroids) > 0
        alpha = face_alpha(mesh.face_area, out, self.buckling)
        for term in self.terms:
            if term.name == "membrane":
                term.alpha = alpha
        self.faces_compensated = int(np.count_nonzero(alpha < 1.0))

    def _fixed_targets(self, t: float) -> np.ndarray | None:
        if not self.scene.handles:
            return None
        x = self.mesh.node_x.copy()
        for handle in self.scene.handles:
            if handle.pinned:
                x[handle.nodes] = handle.targets(t)
        return x

    def _contact_constraints(self) -> ContactConstraints:
        """Free nodes near an obstacle now, with the nearest obstacle's normal and velocity."""
        mesh, scene = self.scene.mesh, self.scene
        self.release_passing()
        free = np.flatnonzero(~self.contact_exempt())
        phi, normal, vel = self.obstacle_set.query(mesh.node_x[free])
        near = np.flatnonzero(phi < scene.thickness * (1.0 + CONTACT_BAND))
        self._inside_at_start = np.union1d(free[phi < 0.0], np.flatnonzero(self.node_passing))
        return ContactConstraints(free[near], np.ascontiguousarray(normal[near]),
                                  np.ascontiguousarray(vel[near]), scene.friction)

    def _implicit_step(self, contacts, timings: dict, stats: dict) -> None:
        """Implicit Euler over the force terms (physics and solve timed apart); advances time."""
        scene, mesh, h = self.scene, self.scene.mesh, self.dt
        m = scene.material
        damping = self.stages.damping
        s, self.last_dv = implicit_euler_step(
            mesh, self.terms, self.pattern, h, self.time,
            m.damping_mass if damping else 0.0,
            m.damping_stiffness if damping else 0.0,
            self._fixed_targets(self.time + h), self.solver, self.last_dv, contacts,
        )
        self.steps_taken += 1
        # frame start + the steps taken within it, counted in exact units of the frame's step /
        # 2**MAX_STEP_HALVINGS: no round-off drift over long runs, so that a frame's time is exactly
        # frame * frame_time (camera cuts and keyframes are given at such times)
        self._ticks += self._step_ticks
        unit = self._frame_dt / 2 ** MAX_STEP_HALVINGS
        last = abs(self._ticks * unit - scene.frame_time) <= 1e-9 * scene.frame_time  # the frame's last step
        self.time = (self.frame + 1) * scene.frame_time if last else self.frame * scene.frame_time + self._ticks * unit
        timings["physics"] += s.time_physics_s
        timings["solve"] += s.time_solve_s
        stats["solver_iterations"] += s.iterations
        stats["solver_iterations_max"] = max(stats["solver_iterations_max"], s.iterations)
        stats["solver_residual"] = max(stats["solver_residual"], s.residual)
        if solve_capped(self.solver, s.iterations, s.residual):
            stats["solves_capped"] += 1
        self.last_energy = s.energy

    def limit_strain(self, stats: dict) -> None:
        """Principal stretches of every face into the material's strain_limits, and v += dx / h
        (cloth.physics.strainlimiting; ARCSim's strain limiting). Counts into `stats`."""
        mesh = self.scene.mesh
        s_min, s_max = self.scene.material.strain_limits
        x_before = mesh.node_x.copy()
        r = limit_strain(mesh, self.pattern, s_min, s_max)
        mesh.node_v += (mesh.node_x - x_before) / self.dt
        for key in STRAIN_LIMIT_RECORD:
            stats[key] = max(stats[key], r[key])

    def contact_exempt(self) -> np.ndarray:
        """(n_nodes,) bool: the nodes obstacle contact leaves alone: pinned, or passing (a node a
        remesh made inside an obstacle, cloth.remeshing.adaptive.PASSING_DEPTH)."""
        return self.mesh.node_pinned | self.node_passing

    def release_passing(self) -> None:
        """Passing nodes that are out of every obstacle are in contact again."""
        passing = np.flatnonzero(self.node_passing)
        if passing.size:
            phi = self.obstacle_set.query(self.mesh.node_x[passing])[0]
            self.node_passing[passing[phi >= 0.0]] = False

    def _project_contacts(self, stats: dict) -> None:
        """Nodes out of the obstacles at the step's end, with friction (counts into `stats`)."""
        mesh, scene = self.scene.mesh, self.scene
        self.obstacle_set.set_time(self.time)
        c = self.contact(mesh.node_x, mesh.node_v, self.contact_exempt(), self.obstacle_set,
                         scene.thickness, scene.friction, self.dt)
        stats["contacts"] = max(stats["contacts"], int(c.get("contacts", 0)))

    def _mesh_obstacle_positions(self) -> list:
        """Vertex positions (copies) of the triangle-mesh obstacles at the current time."""
        for ob in self.mesh_obstacles:
            ob.set_time(self.time)  # a no-op unless the obstacles were moved since the last step
        return [ob.positions.copy() for ob in self.mesh_obstacles]

    def resolve_collisions(self, x_start: np.ndarray, h: float, stats: dict, y_start=None) -> None:
        """The step's collision pass (x_start -> the current positions): cloth-cloth pairs with
        self_collision; with y_start (the mesh obstacles' positions at the step's start, given
        when obstacle_ccd is planned) cloth-obstacle pairs too, in the same pass. Counts into `stats`."""
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
                                                  self_pairs=self.self_collision is not None, skip=skip,
                                                  trees=self._collision_trees)
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
        self._step_gave_up = s["self_collisions_left"] > 0 or s.get("obstacle_collisions_left", 0) > 0

    def _mesh_obstacle_triangles(self) -> list:
        """(positions, faces) of the triangle-mesh obstacles now, [] if none."""
        if not self.mesh_obstacles:
            return []
        self.obstacle_set.set_time(self.time)
        return mesh_obstacle_triangles(self.mesh_obstacles)

    def untangle(self, stats: dict) -> None:
        """Remove crossings of the cloth with itself (with 'self_collision') and with triangle-mesh
        obstacles (in the start state, after a remesh); only the cloth moves. Counts into `stats`."""
        mesh = self.scene.mesh
        s = untangle(mesh.face_nodes, mesh.node_x, mesh.node_m, mesh.node_pinned, self.scene.thickness,
                     UNTANGLE_ITERATIONS, obstacles=self._mesh_obstacle_triangles())
        if stats["untangles"]:  # another this frame: the most found, every iteration, the last one's rest
            s["intersections_found"] = max(s["intersections_found"], stats["intersections_found"])
            s["untangle_iterations"] += stats["untangle_iterations"]
        stats.update(s)
        stats["untangles"] += 1
        self.intersections_pending = int(s["intersections_left"])
        self.untangle_due = False
