"""The stage plan of the frame loop (cloth.simulation): which stages a simulation runs, decided
once, from what the scene declares (``scene.effects``) and what the mode asks for (a remesher,
buckling compensation), and the force terms its implicit step assembles.

Plain data and functions of the scene, not of the simulation: a plan is made before there is a
simulation (:class:`cloth.simulation.Simulation` makes its own in ``__init__``, and again when it
unpickles a checkpoint written before there was a plan), and tests and ablations compare and edit
plans on their own (:meth:`Stages.without`). :mod:`cloth.simulation` re-exports every name here.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace

from cloth.collision.meshobstacle import mesh_obstacles
from cloth.core.measured import MeasuredMaterial
from cloth.core.scene import Scene
from cloth.physics.forces import (
    Bending,
    ForceTerm,
    Gravity,
    HandleSprings,
    MeasuredBending,
    MeasuredMembrane,
    Membrane,
    Wind,
)
from cloth.physics.linsolve import BENDING_HESSIAN_DEFAULT
from cloth.physics.membrane import GAUSS_NEWTON

# Force terms in the order they are assembled (each present only when its effect is declared).
FORCE_EFFECTS = ("membrane", "bending", "gravity", "wind")


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


def build_force_terms(scene: Scene, bending_hessian: str = BENDING_HESSIAN_DEFAULT,
                      membrane_hessian: str = "projected") -> list[ForceTerm]:
    """The force terms of the scene's declared effects, in a fixed order (built once).

    The material's type chooses the elasticity: a Material gets the isotropic StVK membrane and
    one bending stiffness, a MeasuredMaterial ARCSim's measured membrane and per-hinge bending.
    `bending_hessian` and `membrane_hessian` (cloth.physics.linsolve.BENDING_HESSIANS,
    MEMBRANE_HESSIANS): the bending and StVK membrane terms' Hessians."""
    terms: list[ForceTerm] = []
    material = scene.material
    measured = isinstance(material, MeasuredMaterial)
    if "membrane" in scene.effects:
        terms.append(MeasuredMembrane(material) if measured else
                     Membrane(*material.lame(), project=GAUSS_NEWTON if membrane_hessian == "gauss_newton" else True))
    if "bending" in scene.effects:
        project = GAUSS_NEWTON if bending_hessian == "gauss_newton" else True
        terms.append(MeasuredBending(material, project) if measured else Bending(material.bending_stiffness, project))
    if "gravity" in scene.effects:
        terms.append(Gravity(scene.gravity))
    if "wind" in scene.effects:
        w = scene.wind
        terms.append(Wind(w.velocity, w.drag, w.gust_amplitude, w.gust_frequency, w.density, w.drag_tangential))
    if _fading(scene):
        terms.append(HandleSprings(scene.handles))
    return terms
