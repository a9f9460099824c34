"""Procedural scenes: hanging_sheet, sheet_on_sphere, flag.

Each builder takes plain parameters (no Hydra) and returns a :class:`cloth.scene.Scene`.
World axes: z up, metres. `resolution` is the number of grid cells along the sheet's longer
side, so a square sheet has 2 * resolution^2 faces.
"""

from __future__ import annotations

import numpy as np

from .material import Material
from .mesh import grid_mesh
from .obstacles import Plane, Sphere, Static
from .scene import Handle, Scene, SceneError, Wind


def _check_resolution(name: str, resolution: int) -> None:
    if int(resolution) < 1:
        raise SceneError(f"scene {name!r}: resolution must be >= 1 cell, got {resolution}")


def _check_size(name: str, **sizes: float) -> None:
    for key, value in sizes.items():
        if not value > 0:
            raise SceneError(f"scene {name!r}: {key} must be > 0 m, got {value}")


def _jitter(mesh, amplitude: float, seed: int) -> None:
    """Tiny seeded out-of-plane noise that breaks the perfect symmetry of a grid."""
    if amplitude > 0:
        rng = np.random.default_rng(seed)
        mesh.node_x[:, 2] += amplitude * rng.standard_normal(mesh.n_nodes)


def hanging_sheet(material: Material, *, resolution: int = 16, size: float = 1.0, height: float = 1.0,
                  frame_time: float = 1 / 30, steps_per_frame: int = 4, jitter: float = 0.0, seed: int = 0,
                  effects=("membrane", "bending", "gravity", "damping")) -> Scene:
    """A square sheet held by its two corners at y = size, released horizontal: it swings down and hangs."""
    name = "hanging_sheet"
    _check_resolution(name, resolution)
    _check_size(name, size=size)
    n = int(resolution)
    mesh = grid_mesh(size, size, n, n, origin=(-size / 2, 0.0, height))
    _jitter(mesh, jitter, seed)
    corners = np.array([n * (n + 1), (n + 1) * (n + 1) - 1])  # the two corners at v = size
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 handles=[Handle(corners, Static())])


def sheet_on_sphere(material: Material, *, resolution: int = 32, size: float = 1.0, drop_height: float = 0.75,
                    sphere_radius: float = 0.25, thickness: float = 0.005, friction: float = 0.3,
                    frame_time: float = 1 / 30, steps_per_frame: int = 4, jitter: float = 1e-4, seed: int = 0,
                    effects=("membrane", "bending", "gravity", "damping", "obstacles")) -> Scene:
    """A square sheet falls onto a sphere resting on the ground and drapes over both."""
    name = "sheet_on_sphere"
    _check_resolution(name, resolution)
    _check_size(name, size=size, sphere_radius=sphere_radius, drop_height=drop_height)
    n = int(resolution)
    mesh = grid_mesh(size, size, n, n, origin=(-size / 2, -size / 2, drop_height))
    _jitter(mesh, jitter, seed)
    obstacles = [Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
                 Sphere(center=(0.0, 0.0, sphere_radius), radius=sphere_radius)]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=obstacles, thickness=thickness, friction=friction)


def flag(material: Material, *, resolution: int = 30, width: float = 1.5, height: float = 1.0,
         pole_height: float = 2.0, wind_velocity=(6.0, 1.5, 0.0), drag: float = 0.5,
         gust_amplitude: float = 0.3, gust_frequency: float = 0.7, frame_time: float = 1 / 30,
         steps_per_frame: int = 4, jitter: float = 1e-4, seed: int = 0,
         effects=("membrane", "bending", "gravity", "damping", "wind")) -> Scene:
    """A flag pinned along its left edge to a vertical pole, in a gusting wind."""
    name = "flag"
    _check_resolution(name, resolution)
    _check_size(name, width=width, height=height)
    nx = int(resolution)
    ny = max(1, int(round(resolution * height / width)))
    mesh = grid_mesh(width, height, nx, ny, origin=(0.0, 0.0, pole_height - height),
                     axes=((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)))
    rng = np.random.default_rng(seed)
    if jitter > 0:  # out of the flag's plane (y), to let the wind catch it
        mesh.node_x[:, 1] += jitter * rng.standard_normal(mesh.n_nodes)
    pole = np.arange(ny + 1) * (nx + 1)  # the column of nodes at u = 0
    wind = Wind(velocity=tuple(wind_velocity), drag=drag, gust_amplitude=gust_amplitude,
                gust_frequency=gust_frequency) if "wind" in effects else None
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame, wind=wind,
                 handles=[Handle(pole, Static())])


SCENES = {"hanging_sheet": hanging_sheet, "sheet_on_sphere": sheet_on_sphere, "flag": flag}


def build_scene(name: str, material: Material, **params) -> Scene:
    """Build a registered scene by name; unknown names and parameters raise SceneError."""
    if name not in SCENES:
        raise SceneError(f"unknown scene {name!r}; known scenes: {sorted(SCENES)}")
    builder = SCENES[name]
    import inspect
    allowed = {p for p in inspect.signature(builder).parameters if p != "material"}
    unknown = set(params) - allowed
    if unknown:
        raise SceneError(f"scene {name!r}: unknown parameter(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    return builder(material, **params)
