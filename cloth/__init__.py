"""View-dependent adaptive cloth simulation (Koh, Narain and O'Brien 2015) on adaptive anisotropic
remeshing (Narain, Samii and O'Brien 2012). The package reads like one frame of the pipeline:

    cloth.core        mesh, material, scene, per-frame record schemas   (imports nothing of cloth)
    cloth.physics     membrane, bending, buckling filter, force terms, assembly, solve, integrator
    cloth.remeshing   physics sizing field, remesh kernels and driver, pop filter, adaptive stage
    cloth.view        camera, camera paths, view factors (eqs 2-8), the view-dependent stage
    cloth.collision   BVH, CCD, obstacles, contact, self-collision, untangling
    cloth.scenes      scene registry, characters and motions, garments, obstacle bodies
    cloth.simulation  the frame loop: one named stage per line, each present only when declared
    cloth.stages      the stage plan: which stages run, from the scene's effects and the mode
    cloth.stepcontrol, cloth.restart, cloth.framerecord   the frame loop's step control, restart
                      protocol and per-frame record (parts of cloth.simulation.Simulation)
    cloth.runner      the run loop: frames, records and every file a run writes
    cloth.eval        rasteriser and screen-space error (never imported by the simulation)
    cloth.io          OBJ, states, checkpoints, manifest, Rerun, stills

The public classes are importable from here (``from cloth import Simulation, Mesh``); they are
loaded on first use, so that ``import cloth.core.mesh`` does not load the whole solver.
"""

from __future__ import annotations

import importlib

# public name -> module that defines it
_EXPORTS = {
    "Mesh": "cloth.core.mesh", "MeshError": "cloth.core.mesh",
    "Material": "cloth.core.material", "MaterialError": "cloth.core.material",
    "MeasuredMaterial": "cloth.core.measured", "load_arcsim_material": "cloth.core.measured",
    "Scene": "cloth.core.scene", "SceneError": "cloth.core.scene", "Handle": "cloth.core.scene",
    "Wind": "cloth.core.scene",
    "SolverOptions": "cloth.physics.linsolve", "BucklingParams": "cloth.physics.buckling",
    "SizingParams": "cloth.remeshing.sizing", "RemeshParams": "cloth.remeshing.remesh",
    "PopFilterParams": "cloth.remeshing.popfilter", "AdaptiveRemesher": "cloth.remeshing.adaptive",
    "Camera": "cloth.view.camera", "ViewError": "cloth.view.camera", "CameraPath": "cloth.view.paths",
    "ViewParams": "cloth.view.viewdep", "ViewDependentRemesher": "cloth.view.viewdep",
    "ObstacleSet": "cloth.collision.obstacles", "Plane": "cloth.collision.obstacles",
    "Sphere": "cloth.collision.obstacles", "Capsule": "cloth.collision.obstacles",
    "TriangleMeshObstacle": "cloth.collision.meshobstacle", "SelfCollisionParams": "cloth.collision.selfcollision",
    "CollisionOptions": "cloth.collision.selfcollision",
    "Mannequin": "cloth.scenes.character", "build_scene": "cloth.scenes.registry",
    "Simulation": "cloth.simulation", "SimulationDiverged": "cloth.stepcontrol",
    "run": "cloth.runner", "Recorder": "cloth.io.recorder",
}
__all__ = sorted(_EXPORTS)


def __getattr__(name: str):
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'cloth' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value  # later look-ups skip this function
    return value


def __dir__():
    return sorted(set(globals()) | set(__all__))
