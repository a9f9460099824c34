"""A scene: the cloth, its material, what acts on it (its declared effects) and its timing.

A scene lists the effects it needs; :func:`cloth.stages.plan_stages` turns that list (and the
mode's choices) into the stages of the frame loop once, so an effect that is not listed costs nothing.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from cloth.core.material import Material, MaterialError
from cloth.core.measured import MeasuredMaterial, check_strain_limits
from cloth.core.mesh import Mesh

# Effects a scene can declare. membrane and bending are the cloth's own elasticity; the rest act on it.
# self_collision: cloth-cloth contact (proximity, continuous collision detection, impact zones)
# in every step and, in the adaptive modes, untangling of crossings after each remesh.
# strain_limiting: after each implicit step, every face's principal stretches are brought within
# the material's strain_limits (cloth.physics.strainlimiting; a MeasuredMaterial's key).
KNOWN_EFFECTS = frozenset({"membrane", "bending", "gravity", "wind", "damping", "obstacles", "self_collision",
                           "strain_limiting"})


class SceneError(ValueError):
    """An inconsistent scene; the message names the offending key."""


# A handle's phases, in order (:meth:`Handle.phase`).
HANDLE_PHASES = ("waiting", "pinned", "fading", "released")


@dataclass
class Handle:
    """Nodes whose positions follow a prescribed rigid motion (a pin when the motion is static).

    A handle's life follows ARCSim's handles (``start_time``, ``end_time``, ``fade_time``):

    * waiting, t < start_time: it holds nothing, its nodes are free (a remesh keeps them);
    * pinned, start_time <= t < end_time: at the first step that starts at or after start_time it
      takes hold of its nodes where they are then, attached to the motion's frame,
      target(t) = R(t) R(ts)^T (x(ts) - p(ts)) + p(t), and pins them to their targets;
    * fading, end_time <= t < end_time + fade_time: the nodes are free and a spring of
      `stiffness` x s(t), s = (1 - (t - end_time) / fade_time)^4 (ARCSim's strength), pulls each to
      its target (:class:`cloth.physics.forces.HandleSprings`);
    * released, after that: it holds no node.

    :meth:`update`, called by the frame loop at the start of every step, moves it between them.
    """

    nodes: np.ndarray  # (k,) int: node indices
    motion: object  # a cloth.collision.obstacles motion: pose(t) -> (R (3,3), p (3,))
    end_time: float = float("inf")  # s, when the handle stops pinning its nodes
    start_time: float = 0.0  # s, when it takes hold of them
    fade_time: float = 0.0  # s, how long its spring fades after end_time (0: it lets go at once)
    stiffness: float = 1e3  # N/m, the fading spring's stiffness at full strength (ARCSim's magic handle_stiffness)
    local: np.ndarray = field(init=False, default=None)  # (k, 3) positions in the motion's frame
    state: str = field(init=False, default="waiting")  # one of HANDLE_PHASES

    def check(self, where: str) -> None:
        """SceneError naming `where` unless the times and stiffness are consistent."""
        if not (self.start_time >= 0 and self.end_time > self.start_time):
            raise SceneError(f"{where}: a handle needs 0 <= start_time < end_time, got start_time "
                             f"{self.start_time} s, end_time {self.end_time} s")
        if not self.fade_time >= 0 or (self.fade_time > 0 and not self.stiffness > 0):
            raise SceneError(f"{where}: a handle's fade_time must be >= 0 s and a fading handle's stiffness "
                             f"> 0 N/m, got fade_time {self.fade_time}, stiffness {self.stiffness}")

    def phase(self, t: float) -> str:
        if t < self.start_time:
            return "waiting"
        if t < self.end_time:
            return "pinned"
        return "fading" if t < self.end_time + self.fade_time else "released"

    @property
    def pinned(self) -> bool:
        return self.state == "pinned"

    def attach(self, node_x: np.ndarray, t: float = 0.0) -> None:
        """Take hold of the nodes where they are at time t, in the motion's frame then."""
        R, p = self.motion.pose(t)
        self.nodes = np.asarray(self.nodes, dtype=np.int64)
        self.local = (node_x[self.nodes] - p) @ R  # = R^T (x - p), row-wise

    def targets(self, t: float) -> np.ndarray:
        R, p = self.motion.pose(t)
        return self.local @ R.T + p

    def strength(self, t: float) -> float:
        """The fading spring's factor at t (1 at end_time, 0 at end_time + fade_time)."""
        if self.fade_time <= 0:
            return 0.0
        s = min(max(1.0 - (t - self.end_time) / self.fade_time, 0.0), 1.0)
        return s ** 4

    def update(self, node_x: np.ndarray, node_pinned: np.ndarray, t: float) -> bool:
        """Enter the phase of time t (the start of a step): take hold, pin, unpin or let go; edits
        `node_pinned`. True if the phase changed."""
        phase = self.phase(t)
        if phase == self.state:
            return False
        if self.state == "waiting":
            self.attach(node_x, t)
        if phase == "released":
            node_pinned[self.nodes] = False
            self.nodes = np.zeros(0, dtype=np.int64)
            self.local = np.zeros((0, 3))
        else:
            node_pinned[self.nodes] = phase == "pinned"
        self.state = phase
        return True

    def restore(self, t: float) -> None:
        """Set the phase of a run resumed at frame time t (a handle whose start_time is t has not
        taken hold yet: that happens at the next step)."""
        self.state = "waiting" if t <= self.start_time and self.start_time > 0 else self.phase(t)


@dataclass
class Wind:
    velocity: tuple  # m/s, mean wind velocity
    drag: float  # kg/(m^2 s), normal drag coefficient (force per area per m/s of normal speed)
    gust_amplitude: float = 0.0  # fraction of the mean speed
    gust_frequency: float = 0.0  # Hz
    density: float = 0.0  # kg/m^3, quadratic normal pressure rho |v_n| v_n per area (ARCSim's wind density)
    drag_tangential: float = 0.0  # kg/(m^2 s), drag along the cloth (ARCSim's wind drag)


@dataclass
class Scene:
    name: str
    mesh: Mesh
    material: Material | MeasuredMaterial  # isotropic (StVK, one bending stiffness) or ARCSim's measured
    effects: frozenset
    frame_time: float  # s, duration of one output frame
    steps_per_frame: int  # implicit steps per frame
    gravity: tuple = (0.0, 0.0, -9.81)  # m/s^2
    wind: Wind | None = None
    obstacles: list = field(default_factory=list)  # cloth.collision.obstacles.Obstacle instances
    handles: list = field(default_factory=list)  # Handle instances
    thickness: float = 0.005  # m, contact offset kept between cloth and obstacles, and between cloth layers
    friction: float = 0.3  # Coulomb coefficient, cloth against obstacles (and against itself unless self_friction)
    self_friction: float | None = None  # Coulomb coefficient, cloth against cloth; None: `friction`
    # m kept between cloth layers, where it differs from `thickness` (ARCSim's scenes: its hard
    # projection thickness, 0.1 x the repulsion thickness); None: `thickness`
    self_thickness: float | None = None
    # Substeps for fast obstacles: a frame takes enough steps that no triangle-mesh obstacle vertex
    # moves more than this fraction of `thickness` in one step (at least steps_per_frame); None: off.
    obstacle_step: float | None = None
    camera: object | None = None  # a camera path (view-dependent issue), None if the scene has none
    notes: tuple = ()  # what a reader of the results must know (e.g. an effect the scene leaves out)
    # Per-frame measures the scene declares: callables mesh -> {column: value}, added to every
    # frame's record (e.g. the drape test's drape coefficient, cloth.eval.drape.DrapeProbe).
    probes: tuple = ()

    def __post_init__(self) -> None:
        self.effects = frozenset(self.effects)
        unknown = self.effects - KNOWN_EFFECTS
        if unknown:
            raise SceneError(f"scene {self.name!r}: unknown effect(s) {sorted(unknown)}; "
                             f"known: {sorted(KNOWN_EFFECTS)}")
        if "membrane" not in self.effects:
            raise SceneError(f"scene {self.name!r}: effects must include 'membrane' (the cloth's in-plane elasticity)")
        if not self.frame_time > 0:
            raise SceneError(f"scene {self.name!r}: frame_time must be > 0, got {self.frame_time}")
        if int(self.steps_per_frame) < 1:
            raise SceneError(f"scene {self.name!r}: steps_per_frame must be >= 1, got {self.steps_per_frame}")
        if ("wind" in self.effects) != (self.wind is not None):
            raise SceneError(f"scene {self.name!r}: effect 'wind' and the wind settings must come together")
        if ("obstacles" in self.effects) != bool(self.obstacles):
            raise SceneError(f"scene {self.name!r}: effect 'obstacles' and the obstacle list must come together")
        limits = getattr(self.material, "strain_limits", None)
        if "strain_limiting" in self.effects and limits is None:
            raise SceneError(f"scene {self.name!r}: effect 'strain_limiting' is declared but material "
                             f"{self.material.name!r} has no strain_limits")
        if limits is not None and "strain_limiting" not in self.effects:
            raise SceneError(f"scene {self.name!r}: material {self.material.name!r} has strain_limits = {limits} "
                             f"but the scene does not declare the effect 'strain_limiting'")
        if limits is not None:
            try:
                check_strain_limits(limits, f"scene {self.name!r}")
            except MaterialError as e:
                raise SceneError(str(e)) from None
        if self.obstacle_step is not None and not self.obstacle_step > 0:
            raise SceneError(f"scene {self.name!r}: obstacle_step must be > 0 (a fraction of the thickness) or None")
        if self.thickness < 0 or self.friction < 0 or (self.self_friction is not None and self.self_friction < 0):
            raise SceneError(f"scene {self.name!r}: thickness, friction and self_friction must be >= 0")
        if self.self_thickness is not None and not self.self_thickness > 0:
            raise SceneError(f"scene {self.name!r}: self_thickness must be > 0 m or None, got {self.self_thickness!r}")
        self.mesh.update_rest_data(self.material.density)
        for handle in self.handles:
            handle.check(f"scene {self.name!r}")
            handle.nodes = np.asarray(handle.nodes, dtype=np.int64)
            handle.state, handle.local = "waiting", np.zeros((handle.nodes.size, 3))
            self.mesh.node_pinned[handle.nodes] = False
            handle.update(self.mesh.node_x, self.mesh.node_pinned, 0.0)

    @property
    def dt(self) -> float:
        return self.frame_time / self.steps_per_frame
