"""A scene: the cloth, its material, what acts on it (its declared effects) and its timing.

A scene lists the effects it needs; :func:`cloth.simulation.plan_stages` turns that list (and the
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


@dataclass
class Handle:
    """Nodes whose positions follow a prescribed rigid motion (a pin when the motion is static).

    The nodes' positions at t = 0 are taken as attached to the moving frame:
    target(t) = R(t) R(0)^T (x(0) - p(0)) + p(t). At `end_time` the handle lets go: its nodes
    become free (:meth:`release`, called by the frame loop before the first step that starts at
    or after it) and it holds no node from then on (ARCSim's handles' `end_time`).
    """

    nodes: np.ndarray  # (k,) int: node indices
    motion: object  # a cloth.collision.obstacles motion: pose(t) -> (R (3,3), p (3,))
    end_time: float = float("inf")  # s, when the handle releases its nodes
    local: np.ndarray = field(init=False, default=None)  # (k, 3) positions in the motion's frame

    def attach(self, node_x: np.ndarray) -> None:
        R0, p0 = self.motion.pose(0.0)
        self.nodes = np.asarray(self.nodes, dtype=np.int64)
        self.local = (node_x[self.nodes] - p0) @ R0  # = R0^T (x - p0), row-wise

    def targets(self, t: float) -> np.ndarray:
        R, p = self.motion.pose(t)
        return self.local @ R.T + p

    def release(self, node_pinned: np.ndarray, t: float) -> bool:
        """At or after end_time, unpin the nodes (edits `node_pinned`) and hold none; True if it did."""
        if t < self.end_time or self.nodes.size == 0:
            return False
        node_pinned[self.nodes] = False
        self.nodes = np.zeros(0, dtype=np.int64)
        self.local = np.zeros((0, 3))
        return True


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
        self.mesh.update_rest_data(self.material.density)
        for handle in self.handles:
            if not handle.end_time > 0:
                raise SceneError(f"scene {self.name!r}: a handle's end_time must be > 0 s, got {handle.end_time}")
            handle.attach(self.mesh.node_x)
            self.mesh.node_pinned[handle.nodes] = True

    @property
    def dt(self) -> float:
        return self.frame_time / self.steps_per_frame
