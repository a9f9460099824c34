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
"""

from __future__ import annotations

import time
from dataclasses import dataclass, fields, replace

import numpy as np

from cloth.collision.contact import resolve_obstacle_contacts
from cloth.collision.meshobstacle import mesh_obstacle_triangles, mesh_obstacles
from cloth.collision.obstacles import ObstacleSet
from cloth.collision.selfcollision import (
    SelfCollisionParams,
    resolve_collisions_with_obstacles,
    resolve_self_collisions,
)
from cloth.collision.untangle import untangle
from cloth.core.measured import MeasuredMaterial
from cloth.core.mesh import Mesh
from cloth.core.records import (
    COLLISION_RECORD,
    PHASES,
    REMESH_RECORD,
    SIM_PHASES,
    STEP_RECORD,
    STRAIN_LIMIT_RECORD,
    VIEW_RECORD,
)
from cloth.core.scene import Scene
from cloth.core.transfer import transfer_node_values
from cloth.physics.assembly import SparsityPattern
from cloth.physics.buckling import compressive_energy, face_alpha
from cloth.physics.forces import (
    Bending,
    ForceTerm,
    Gravity,
    HandleSprings,
    MeasuredBending,
    MeasuredMembrane,
    Membrane,
    Wind,
    element_families,
)
from cloth.physics.integrator import ContactConstraints, implicit_euler_step
from cloth.physics.linsolve import SolverOptions, solve_capped
from cloth.physics.measured_membrane import measured_compressive_energy
from cloth.physics.strainlimiting import limit_strain
from cloth.view.factors import face_geometry, face_view_data

# A free node within (1 + CONTACT_BAND) x thickness of an obstacle at the start of a step is a
# contact candidate for the solve (projection leaves resting nodes at exactly the thickness).
CONTACT_BAND = 0.5
# Bound of the contour-minimisation iterations after a remesh (the record says what is left).
UNTANGLE_ITERATIONS = 30
# Force terms in the order they are assembled (each present only when its effect is declared).
FORCE_EFFECTS = ("membrane", "bending", "gravity", "wind")


# Step control. A step whose result fails a check (STEP_CHECKS) is undone (the state before it
# restored) and taken again as two steps of half its length, each checked the same way, at most
# MAX_STEP_HALVINGS times in a row: down to a step of dt / 16. A step that still fails then ends
# the run (SimulationDiverged), except a collision pass that gave up: at the finest step it is
# accepted and the cloth untangled before the next step, as without step control.
MAX_STEP_HALVINGS = 4
# A step may not raise the free nodes' kinetic energy above KE_JUMP_FACTOR times the energy the
# cloth had to move with at its start: its kinetic energy, its elastic (membrane and bending)
# energy, which a step may release into motion, and a floor, its mass moving at
# KE_FLOOR_SPEED_M_S (so that a cloth at rest may start to fall and a body may strike it).
# Implicit Euler dissipates: gravity, the handles and the obstacles are the only sources, and none
# multiplies that energy tenfold in a step of a frame or less; one bad hinge did (issue 32: a
# dancer's bending gradient went from 0.42 to 147 N in one step, and the cloth to 595 m/s within
# the frame). Without the elastic energy in the budget, a stiff sheet (100 x cotton, the stability
# suite's stiff_material) releasing 47 J of membrane energy into 1.7 J of motion was a jump.
KE_JUMP_FACTOR = 10.0
KE_FLOOR_SPEED_M_S = 1.0


class SimulationDiverged(RuntimeError):
    """A step failed its checks (non-finite state, a node over the speed limit, a jump of the
    kinetic energy) at every halving of its length that step control allows. `frame` is the frame
    it happened in and `rejected` what step control did in it, by STEP_RECORD column (that frame
    has no record: the run's summary counts it from here; dt_min_s is the last step tried)."""

    def __init__(self, message: str, frame: int | None = None, rejected: dict | None = None):
        super().__init__(message)
        self.frame = frame
        self.rejected = dict(rejected or {})


@dataclass(frozen=True)
class Stages:
    """The stages a simulation runs, decided once (:func:`plan_stages`). False: never called."""

    forces: tuple = ()  # force terms assembled in the implicit step, by effect name (FORCE_EFFECTS), and
    # 'handle_springs' when a handle fades (its springs after end_time)
    damping: bool = False  # Rayleigh damping in the implicit step ('damping')
    remesh: bool = False  # the mode's remesh stage (mode=adaptive, viewdep)
    untangle: bool = False  # remove crossings (self_collision, mesh obstacles): start, remesh, given-up collisions
    buckling: bool = False  # compression factors of the out-of-frustum faces (the mode's buckling)
    obstacle_contact: bool = False  # node contact with every obstacle, in the solve and after it ('obstacles')
    obstacle_ccd: bool = False  # cloth against triangle-mesh obstacles: proximity, CCD, impact zones
    self_collision: bool = False  # cloth against itself: proximity, CCD, impact zones ('self_collision')
    strain_limiting: bool = False  # principal stretches into the material's limits after each step

    def names(self) -> list[str]:
        """The planned stages, by name (force terms as 'force:<effect>'), for records and tests."""
        out = [f"force:{f}" for f in self.forces]
        return out + [f.name for f in fields(self) if f.name != "forces" and getattr(self, f.name)]

    def without(self, *names: str) -> Stages:
        """This plan with the named stages switched off (an ablation; a test of a stage's effect)."""
        switches = [f.name for f in fields(self) if f.name != "forces"]
        unknown = set(names) - set(switches)
        if unknown:
            raise ValueError(f"unknown stage(s) {sorted(unknown)}; stages that switch: {switches}")
        return replace(self, **{name: False for name in names})


def _fading(scene: Scene) -> bool:
    """Whether a handle of the scene fades (its springs are then a force term of the step)."""
    return any(h.fade_time > 0 for h in scene.handles)


def plan_stages(scene: Scene, remesher=None, buckling=None) -> Stages:
    """The one place where what a scene declares and what a mode asks for become stages.

    Scene effects: membrane, bending, gravity, wind (force terms), damping, obstacles (node
    contact with every obstacle; with triangle-mesh obstacles and a thickness > 0, also their
    triangles in the step's collision pass), self_collision, strain_limiting; untangling wherever
    crossings can arise (self_collision or mesh obstacles: a start state, a remesh). Mode: a
    remesher (remesh), buckling parameters (buckling).
    """
    effects = scene.effects
    obstacles = "obstacles" in effects
    meshes = obstacles and bool(mesh_obstacles(scene.obstacles))
    self_collision = "self_collision" in effects
    remesh = remesher is not None
    return Stages(
        forces=tuple(e for e in FORCE_EFFECTS if e in effects) + (("handle_springs",) if _fading(scene) else ()),
        damping="damping" in effects,
        remesh=remesh,
        untangle=self_collision or meshes,
        buckling=buckling is not None,
        obstacle_contact=obstacles,
        obstacle_ccd=meshes and scene.thickness > 0,
        self_collision=self_collision,
        strain_limiting="strain_limiting" in effects,
    )


def build_force_terms(scene: Scene) -> list[ForceTerm]:
    """The force terms of the scene's declared effects, in a fixed order (built once).

    The material's type chooses the elasticity: a Material gets the isotropic StVK membrane and
    one bending stiffness, a MeasuredMaterial ARCSim's measured membrane and per-hinge bending."""
    terms: list[ForceTerm] = []
    material = scene.material
    measured = isinstance(material, MeasuredMaterial)
    if "membrane" in scene.effects:
        terms.append(MeasuredMembrane(material) if measured else Membrane(*material.lame()))
    if "bending" in scene.effects:
        terms.append(MeasuredBending(material) if measured else Bending(material.bending_stiffness))
    if "gravity" in scene.effects:
        terms.append(Gravity(scene.gravity))
    if "wind" in scene.effects:
        w = scene.wind
        terms.append(Wind(w.velocity, w.drag, w.gust_amplitude, w.gust_frequency, w.density, w.drag_tangential))
    if _fading(scene):
        terms.append(HandleSprings(scene.handles))
    return terms


class Remesher:
    """Interface of the remesh stage (cloth.remeshing.adaptive.AdaptiveRemesher implements it).

    `remesh(sim, timings, stats)` may replace `sim.scene.mesh`; when it does, it calls
    `sim.rebuild()` (masses, rest data, sparsity: only then) and returns True. It adds its
    wall time to timings['sizing'] and timings['remesh'] and its counters to `stats`.
    """

    def remesh(self, sim: Simulation, timings: dict, stats: dict) -> bool:  # pragma: no cover - interface
        raise NotImplementedError


class Simulation:
    def __init__(self, scene: Scene, solver: SolverOptions | None = None,
                 remesher: Remesher | None = None, max_speed: float = 100.0, buckling=None):
        """`buckling` (cloth.physics.buckling.BucklingParams or None): buckling compensation on the
        faces outside the camera's frustum; needs `scene.camera` (a cloth.view.paths.CameraPath)."""
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
        self.terms = build_force_terms(scene)
        # What the stages use (None when their stage is not planned). The remesh stage reads
        # `contact`, `obstacle_set` and `self_collision` to keep a remesh clear of obstacles and
        # of crossings.
        self.contact = resolve_obstacle_contacts if self.stages.obstacle_contact else None
        self.obstacle_set = ObstacleSet(scene.obstacles) if self.stages.obstacle_contact else None
        self.mesh_obstacles = mesh_obstacles(scene.obstacles) if self.stages.obstacle_contact else []
        self_friction = scene.friction if scene.self_friction is None else scene.self_friction
        self.self_collision = (SelfCollisionParams(thickness=scene.thickness, friction=self_friction,
                                                   self_thickness=scene.self_thickness)
                               if self.stages.self_collision else None)
        self.mesh_collision = (self.self_collision or SelfCollisionParams(thickness=scene.thickness,
                                                                          friction=scene.friction)
                               if self.stages.obstacle_ccd else None)
        self._inside_at_start = None  # free nodes inside an obstacle at the step's start (obstacle_ccd skips them)
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

    def __setstate__(self, state: dict) -> None:
        """Unpickle (checkpoints); a checkpoint of code before the stage plan gets its plan here."""
        self.__dict__.update(state)
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

    # ---- restarting from another run's state -------------------------------------------------
    def restart_from(self, state: dict) -> None:
        """Continue from a saved state of a run of the same scene (cloth.io.states with restart data,
        possibly of another mode or resolution) at its frame: the re-synchronised error starts
        every mode from the reference's state.

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
        handle_ids = np.asarray(state["node_handle"])
        if handle_ids.size and int(handle_ids.max()) >= len(scene.handles):
            raise ValueError(f"the state has {int(handle_ids.max()) + 1} handles, this scene {len(scene.handles)}")
        if self.remesher is not None:
            scene.mesh = Mesh(node_x=np.array(state["node_x"], dtype=np.float64),
                              node_v=np.array(state["node_v"], dtype=np.float64),
                              node_pinned=np.array(state["node_pinned"], dtype=bool),
                              vert_u=np.array(state["vert_u"], dtype=np.float64),
                              vert_node=state["vert_node"], face_verts=state["face_verts"],
                              density=scene.material.density)
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

    # ---- the frame -------------------------------------------------------------------------
    def advance_frame(self) -> dict:
        """Simulate one frame; return its record (one row of frames.parquet, without I/O time).

        Times: time_<phase>_s per phase (PHASES), sim_s = the sum over SIM_PHASES (simulation
        time, the paper's Time/Frame), wall_s = the whole call (the runner adds its I/O to it)."""
        t_start = time.perf_counter()
        timings = {p: 0.0 for p in PHASES}
        stats = {"steps": 0, "solver_iterations": 0, "solver_iterations_max": 0, "solver_residual": 0.0,
                 "solves_capped": 0, "contacts": 0, **STEP_RECORD,
                 **REMESH_RECORD, **VIEW_RECORD, **COLLISION_RECORD, **STRAIN_LIMIT_RECORD}
        stages = self.stages
        changed = stages.remesh and self.remesher.remesh(self, timings, stats)
        if stages.untangle and (changed or self.untangle_due or self.intersections_pending > 0):
            # the start state (a fixed mesh made from a coarse garment can cross a body between
            # its nodes), after a remesh that changed the mesh, and in every frame after one that
            # left crossings (the record then says what is still left, not 0)
            self._timed(timings, "collisions", self.untangle, stats)
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
        record["time_other_s"] = max(wall - sum(timings[p] for p in PHASES if p != "other"), 0.0)
        record["sim_s"] = sum(timings[p] for p in SIM_PHASES)  # the paper's Time/Frame
        record["wall_s"] = wall
        return record

    def obstacle_steps(self) -> int:
        """Steps this frame needs so that no mesh-obstacle vertex moves more than scene.obstacle_step
        x thickness in one step: the fastest vertex speed at the frame's start, middle and end,
        times the frame time, over that distance (a contact is then found before it is passed)."""
        scene = self.scene
        speed = 0.0
        for ob in self.mesh_obstacles:
            for a in (0.0, 0.5, 1.0):
                _, v = ob.state_at(self.time + a * scene.frame_time)
                speed = max(speed, float(np.sqrt((v * v).sum(axis=1).max())) if v.size else 0.0)
        return max(int(np.ceil(speed * scene.frame_time / (scene.obstacle_step * scene.thickness))), 1)

    def _controlled_step(self, halvings: int, timings: dict, stats: dict) -> None:
        """One step of the frame's step / 2**halvings under step control: taken, checked
        (:meth:`step_failure`) and, if it fails, undone and taken as two steps of half the length.
        Counts the rejections into `stats` (steps_rejected, steps_rejected_<check>, dt_min_s)."""
        self.dt = self._frame_dt / 2 ** halvings
        self._step_ticks = 2 ** (MAX_STEP_HALVINGS - halvings)
        for handle in self.scene.handles:  # take hold, pin, let a spring fade, let go (Handle.update) at the
            # step's start; idempotent, so a step taken again finds the phase it had
            handle.update(self.mesh.node_x, self.mesh.node_pinned, self.time)
        saved = self._save_step_state()
        self.step(timings, stats)
        failure = self.step_failure(saved["kinetic_energy"])
        finest = halvings == MAX_STEP_HALVINGS
        if failure is not None and not (finest and failure == "collisions"):
            stats["steps_rejected"] += 1
            stats[f"steps_rejected_{failure}"] += 1
            if finest:
                raise SimulationDiverged(
                    f"frame {self.frame + 1}: {self._failure_message(failure)} at t = {self.time:.4f} s, in a step "
                    f"of {self.dt:.3g} s taken again {MAX_STEP_HALVINGS} times at half the length "
                    f"(MAX_STEP_HALVINGS)", frame=self.frame + 1,
                    rejected={**{k: stats[k] for k in STEP_RECORD if k.startswith("steps_rejected")},
                              "dt_min_s": self.dt})
            self._restore_step_state(saved)
            for _ in range(2):
                self._controlled_step(halvings + 1, timings, stats)
            return
        self._substep += 1
        stats["dt_min_s"] = min(stats["dt_min_s"], self.dt)
        if self.stages.untangle and self._step_gave_up:
            # a collision pass gave up at the finest step: the cloth may now cross itself or a
            # body. Untangled before the next step, whose collision pass needs a clean start (a
            # fixed dress kept 12 such crossings for 165 frames; untangled only at the next
            # frame's start, frames 335-337 of its dance still ended crossing)
            self._timed(timings, "collisions", self.untangle, stats)

    def _free_kinetic_energy(self) -> tuple[float, float]:
        """(kinetic energy of the free nodes in J, their mass in kg)."""
        mesh = self.scene.mesh
        free = ~mesh.node_pinned
        m = mesh.node_m[free]
        v = mesh.node_v[free]
        return float(0.5 * np.sum(m * np.einsum("ij,ij->i", v, v))), float(m.sum())

    def _save_step_state(self) -> dict:
        """What a step changes, to undo it (positions, velocities, pins, the time, the warm start)."""
        mesh = self.scene.mesh
        return {"node_x": mesh.node_x.copy(), "node_v": mesh.node_v.copy(), "node_pinned": mesh.node_pinned.copy(),
                "time": self.time, "ticks": self._ticks, "last_dv": self.last_dv, "last_energy": self.last_energy,
                "steps_taken": self.steps_taken, "kinetic_energy": self._free_kinetic_energy()}

    def _restore_step_state(self, saved: dict) -> None:
        mesh = self.scene.mesh
        mesh.node_x[:] = saved["node_x"]
        mesh.node_v[:] = saved["node_v"]
        mesh.node_pinned[:] = saved["node_pinned"]
        self.time, self._ticks, self.steps_taken = saved["time"], saved["ticks"], saved["steps_taken"]
        self.last_dv, self.last_energy = None, saved["last_energy"]  # a failed solve is no warm start
        if self.stages.obstacle_contact:
            self.obstacle_set.set_time(self.time)

    def step_failure(self, kinetic_energy_before: tuple[float, float]) -> str | None:
        """The first of STEP_CHECKS the step just taken fails, or None. `kinetic_energy_before`:
        (J, kg) of the free nodes before it (:meth:`_free_kinetic_energy`)."""
        mesh = self.scene.mesh
        if not (np.all(np.isfinite(mesh.node_x)) and np.all(np.isfinite(mesh.node_v))):
            return "non_finite"
        if len(mesh.node_v) and float(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))) > self.max_speed ** 2:
            return "speed"
        if self._free_kinetic_energy()[0] > self._kinetic_energy_bound(kinetic_energy_before):
            return "kinetic_energy"
        if self._step_gave_up:
            return "collisions"
        return None

    def _kinetic_energy_bound(self, kinetic_energy_before: tuple[float, float]) -> float:
        """J: KE_JUMP_FACTOR x (the free nodes' kinetic energy before the step + the elastic energy
        at its start + their mass at KE_FLOOR_SPEED_M_S)."""
        ke_before, mass = kinetic_energy_before
        energy = self.last_energy  # the implicit step's, at the step's start
        elastic = max(float(energy.get("membrane", 0.0) + energy.get("bending", 0.0)), 0.0)
        return KE_JUMP_FACTOR * (ke_before + elastic + 0.5 * mass * KE_FLOOR_SPEED_M_S ** 2)

    def _failure_message(self, failure: str) -> str:
        mesh = self.scene.mesh
        if failure == "non_finite":
            return "non-finite node positions or velocities"
        if failure == "speed":
            speed = float(np.sqrt(np.max(np.einsum("ij,ij->i", mesh.node_v, mesh.node_v))))
            return f"node speed {speed:.3g} m/s exceeds max_speed = {self.max_speed:g} m/s"
        ke, _ = self._free_kinetic_energy()
        return (f"kinetic energy {ke:.3g} J more than KE_JUMP_FACTOR = {KE_JUMP_FACTOR:g} times the kinetic and "
                f"elastic energy before the step (with a floor of the cloth's mass at {KE_FLOOR_SPEED_M_S:g} m/s)")

    def step(self, timings: dict, stats: dict) -> None:
        """One implicit step of length self.dt with its contact and collision stages (unchecked:
        :meth:`_controlled_step` checks it, and undoes it if it fails)."""
        stages, mesh, h = self.stages, self.scene.mesh, self.dt  # the handles' phases: _controlled_step
        collide = stages.self_collision or stages.obstacle_ccd
        self._step_gave_up = False  # set by resolve_collisions when its pass leaves collisions
        x_start = mesh.node_x.copy() if collide else None
        y_start = self._mesh_obstacle_positions() if stages.obstacle_ccd else None
        contacts = self._timed(timings, "collisions", self._contact_constraints) if stages.obstacle_contact else None
        self._implicit_step(contacts, timings, stats)
        if stages.strain_limiting:
            self._timed(timings, "physics", self.limit_strain, stats)
        if stages.obstacle_contact:
            self._timed(timings, "collisions", self._project_contacts, stats)
        if collide:  # cloth-obstacle (with obstacle_ccd) and cloth-cloth collisions, in one pass
            self._timed(timings, "collisions", self.resolve_collisions, x_start, h, stats, y_start)

    @staticmethod
    def _timed(timings: dict, phase: str, stage, *args):
        """Run `stage(*args)`, adding its wall time to timings[phase] (accumulates into timings)."""
        t0 = time.perf_counter()
        out = stage(*args)
        timings[phase] += time.perf_counter() - t0
        return out

    # ---- the stages ------------------------------------------------------------------------
    def update_buckling(self) -> None:
        """Compression factors (paper eq 11) of the faces out of the frustum of the camera now."""
        if self.buckling is None:
            return
        mesh = self.scene.mesh
        camera = self.scene.camera.camera_at(self.time)
        out = camera.distance_to_frustum(mesh.node_x[mesh.face_nodes].mean(axis=1)) > 0
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

    # ---- the record ------------------------------------------------------------------------
    def view_counts(self) -> dict:
        """Faces in view (in the frustum and facing the camera), back-facing in frame, out of frame,
        and compressive_energy_out_j (cloth.physics.buckling.compressive_energy of the faces out
        of the frame). NaN without a camera. The same definitions as the view-dependent sizing
        (face centroids)."""
        nan = float("nan")
        if self.scene.camera is None:
            return {"faces_in_view": nan, "faces_back_facing": nan, "faces_out_of_frame": nan,
                    "faces_compensated": nan, "compressive_energy_out_j": nan}
        c, n = face_geometry(self.scene.mesh)
        d, front = face_view_data(self.scene.camera.camera_at(self.time), c, n)
        inside = d == 0
        return {"faces_in_view": int(np.count_nonzero(inside & front)),
                "faces_back_facing": int(np.count_nonzero(inside & ~front)),
                "faces_out_of_frame": int(np.count_nonzero(~inside)),
                "faces_compensated": self.faces_compensated if self.buckling is not None else 0,
                "compressive_energy_out_j": self.compressive_energy(np.flatnonzero(~inside))}

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
