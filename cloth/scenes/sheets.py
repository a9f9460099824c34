"""Sheet scenes: hanging_sheet, sheet_on_sphere, flag, layered_sheets, crushed_sheet,
mesh_obstacle and the Cusick drape test (cusick_drape).

Each builder takes plain parameters (no Hydra) and returns a :class:`cloth.core.scene.Scene`.
Its defaults are conf/scene/<name>.yaml's `params` and its `scales.small.resolution`, so that
`build_scene(name, material)` is the scene `python -m experiments.run scene=<name>` runs
(tests/test_scene_defaults.py builds every scene both ways).
World axes: z up, metres. `resolution` is the number of grid cells along the sheet's longer
side, so a square sheet has 2 * resolution^2 faces.
"""

from __future__ import annotations

import numpy as np

from cloth.collision.meshobstacle import MeshObstacleError, TriangleMeshObstacle
from cloth.collision.obstacles import Plane, Ramp, Sphere, Static
from cloth.core.material import Material
from cloth.core.mesh import grid_mesh, merge_meshes
from cloth.core.scene import Handle, Scene, SceneError, Wind
from cloth.eval.drape import DrapeProbe
from cloth.io.obj import ObjError, load_obj_sequence
from cloth.scenes.bodies import moving_sphere_keyframes
from cloth.scenes.common import _check_resolution, _check_size, _jitter
from cloth.scenes.garments import uniform_annulus_mesh


def hanging_sheet(material: Material, *, resolution: int = 20, size: float = 1.0, height: float = 1.0,
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


def _on_sphere_and_ground(name, mesh, material, effects, sphere_radius, frame_time, steps_per_frame,
                          thickness, friction) -> Scene:
    """The Scene of cloth `mesh` above the ground (z = 0) and a sphere of `sphere_radius` resting on
    it at the origin (sheet_on_sphere, layered_sheets)."""
    obstacles = [Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
                 Sphere(center=(0.0, 0.0, sphere_radius), radius=sphere_radius)]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=obstacles, thickness=thickness, friction=friction)


def sheet_on_sphere(material: Material, *, resolution: int = 24, size: float = 1.0, drop_height: float = 0.75,
                    sphere_radius: float = 0.25, thickness: float = 0.005, friction: float = 0.3,
                    frame_time: float = 0.04, steps_per_frame: int = 8, jitter: float = 1e-4, seed: int = 0,
                    effects=("membrane", "bending", "gravity", "damping", "obstacles")) -> Scene:
    """A square sheet falls onto a sphere resting on the ground and drapes over both."""
    name = "sheet_on_sphere"
    _check_resolution(name, resolution)
    _check_size(name, size=size, sphere_radius=sphere_radius, drop_height=drop_height)
    n = int(resolution)
    mesh = grid_mesh(size, size, n, n, origin=(-size / 2, -size / 2, drop_height))
    _jitter(mesh, jitter, seed)
    return _on_sphere_and_ground(name, mesh, material, effects, sphere_radius, frame_time, steps_per_frame,
                                 thickness, friction)


def flag(material: Material, *, resolution: int = 24, width: float = 1.5, height: float = 1.0,
         pole_height: float = 2.0, wind_velocity=(6.0, 1.5, 0.0), drag: float = 0.5,
         gust_amplitude: float = 0.3, gust_frequency: float = 0.7, frame_time: float = 0.04,
         steps_per_frame: int = 8, jitter: float = 1e-4, seed: int = 0,
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


def layered_sheets(material: Material, *, resolution: int = 12, size: float = 0.5, layers: int = 2,
                   spacing: float = 0.02, drop_height: float = 0.3, sphere_radius: float = 0.12,
                   thickness: float = 0.005, friction: float = 0.3, frame_time: float = 0.04,
                   steps_per_frame: int = 8, jitter: float = 1e-4, seed: int = 0, cell_aspect: float = 1.0,
                   effects=("membrane", "bending", "gravity", "damping", "obstacles", "self_collision")) -> Scene:
    """`layers` square sheets stacked `spacing` apart fall onto a sphere on the ground: the
    upper sheets land on the lower ones (cloth-cloth contact between separate pieces).
    `cell_aspect` > 1 makes the input grid's cells that many times longer (in y) than wide, so
    the input triangles are thin (the stability suite's thin-triangle case)."""
    name = "layered_sheets"
    _check_resolution(name, resolution)
    _check_size(name, size=size, spacing=spacing, drop_height=drop_height, sphere_radius=sphere_radius)
    if int(layers) < 1:
        raise SceneError(f"scene {name!r}: layers must be >= 1, got {layers}")
    if not cell_aspect >= 1:
        raise SceneError(f"scene {name!r}: cell_aspect must be >= 1, got {cell_aspect}")
    n = int(resolution)
    ny = max(1, int(round(n / cell_aspect)))
    sheets = [grid_mesh(size, size, n, ny, origin=(-size / 2 + 0.01 * k, -size / 2, drop_height + k * spacing))
              for k in range(int(layers))]
    mesh = merge_meshes(sheets)
    _jitter(mesh, jitter, seed)
    return _on_sphere_and_ground(name, mesh, material, effects, sphere_radius, frame_time, steps_per_frame,
                                 thickness, friction)


def crushed_sheet(material: Material, *, resolution: int = 24, length: float = 0.8, width: float = 0.25,
                  drop_height: float = 0.02, tilt_deg: float = 8.0, gap: float = 0.04, press_start: float = 0.8,
                  press_duration: float = 0.6, thickness: float = 0.005, friction: float = 0.3,
                  frame_time: float = 0.04, steps_per_frame: int = 8, jitter: float = 1e-3, seed: int = 0,
                  effects=("membrane", "bending", "gravity", "damping", "obstacles", "self_collision")) -> Scene:
    """Dense self-contact: a strip released standing on its short edge collapses onto the
    ground in folds that pile on each other; then a plate comes down and presses the pile to
    `gap` above the ground (the stability suite's crushed sheet)."""
    name = "crushed_sheet"
    _check_resolution(name, resolution)
    _check_size(name, length=length, width=width, gap=gap, press_duration=press_duration)
    if gap <= 2 * thickness:
        raise SceneError(f"scene {name!r}: gap ({gap} m) must exceed twice the thickness ({thickness} m)")
    n = int(resolution)
    ny = max(1, int(round(n * width / length)))
    tilt = np.radians(tilt_deg)
    up = (0.0, np.sin(tilt), np.cos(tilt))  # the strip's long side, tilted so that it folds one way
    mesh = grid_mesh(width, length, ny, n, origin=(-width / 2, 0.0, drop_height), axes=((1.0, 0.0, 0.0), up))
    rng = np.random.default_rng(seed)
    mesh.node_x[:, 1] += jitter * rng.standard_normal(mesh.n_nodes)
    top = float(mesh.node_x[:, 2].max()) + 0.05
    plate = Plane(point=(0.0, 0.0, top), normal=(0.0, 0.0, -1.0), display_size=1.0, name="plate",
                  motion=Ramp((0.0, 0.0, gap - top), press_start, press_start + press_duration))
    obstacles = [Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)), plate]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=obstacles, thickness=thickness, friction=friction)


def mesh_obstacle(material: Material, *, resolution: int = 24, size: float = 1.0, drop_height: float = 0.75,
                  obstacle_obj=None, obstacle_scale: float = 1.0, obstacle_offset=(0.0, 0.0, 0.0),
                  obstacle_frame_time: float = 0.04, obstacle_query_radius=None, sphere_radius: float = 0.25,
                  sphere_subdivisions: int = 2, sphere_travel=(0.15, 0.0, 0.0), sphere_period: float = 2.0,
                  sphere_keyframes: int = 50, ground: bool = True, thickness: float = 0.005,
                  friction: float = 0.3, frame_time: float = 0.04, steps_per_frame: int = 8,
                  jitter: float = 1e-4, seed: int = 0,
                  effects=("membrane", "bending", "gravity", "damping", "obstacles")) -> Scene:
    """A square sheet falls onto an animated triangle-mesh obstacle (cloth.collision.meshobstacle) on the ground.

    The obstacle is the OBJ sequence `obstacle_obj` (a glob pattern such as 'walk/frame_*.obj', a
    directory of .obj files, or a list of files; one topology; positions x `obstacle_scale` +
    `obstacle_offset`, m; one file every `obstacle_frame_time` s, linear in between, held after
    the last), or by default an icosphere (`sphere_radius`, `sphere_subdivisions`) resting on the
    ground whose centre swings by `sphere_travel` sin(2 pi t / `sphere_period`), given as
    `sphere_keyframes` keyframes `obstacle_frame_time` apart (the same path as an OBJ sequence
    written by `python -m experiments.obstacle_obj DIR`)."""
    name = "mesh_obstacle"
    _check_resolution(name, resolution)
    _check_size(name, size=size, drop_height=drop_height, obstacle_frame_time=obstacle_frame_time)
    offset = np.asarray(obstacle_offset, dtype=np.float64)
    if offset.shape != (3,):
        raise SceneError(f"scene {name!r}: obstacle_offset must be three numbers (m), got {obstacle_offset!r}")
    try:
        if obstacle_obj is not None:
            X, F, _ = load_obj_sequence(obstacle_obj, scale=obstacle_scale)
        else:
            _check_size(name, sphere_radius=sphere_radius, sphere_period=sphere_period)
            if int(sphere_keyframes) < 1:
                raise SceneError(f"scene {name!r}: sphere_keyframes must be >= 1, got {sphere_keyframes}")
            if np.shape(sphere_travel) != (3,):
                raise SceneError(f"scene {name!r}: sphere_travel must be three numbers (m), got {sphere_travel!r}")
            t = np.arange(int(sphere_keyframes)) * obstacle_frame_time
            centers = np.array([0.0, 0.0, sphere_radius]) + np.sin(2 * np.pi * t / sphere_period)[:, None] \
                * np.asarray(sphere_travel, dtype=np.float64)
            X, F = moving_sphere_keyframes(sphere_radius, sphere_subdivisions, centers)
        body = TriangleMeshObstacle(X + offset, F, obstacle_frame_time, query_radius=obstacle_query_radius,
                                    name="mesh_obstacle")
    except (MeshObstacleError, ObjError) as exc:
        key = "obstacle_obj" if obstacle_obj is not None else "obstacle"
        raise SceneError(f"scene {name!r}: {key}: {exc}") from None
    n = int(resolution)
    mesh = grid_mesh(size, size, n, n, origin=(-size / 2, -size / 2, drop_height))
    _jitter(mesh, jitter, seed)
    obstacles = ([Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0))] if ground else []) + [body]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=obstacles if "obstacles" in effects else [], thickness=thickness, friction=friction)


def cusick_drape(material: Material, *, resolution: int = 48, specimen_radius: float = 0.15,
                 support_radius: float = 0.09, height: float = 0.6, frame_time: float = 0.04,
                 steps_per_frame: int = 8, jitter: float = 1e-4, seed: int = 0,
                 effects=("membrane", "bending", "gravity", "damping")) -> Scene:
    """The Cusick drape test (ISO 9073-9, BS 5058): a flat circular specimen of `specimen_radius`
    clamped between two discs of `support_radius` at `height` m, which drapes under gravity into
    folds. The specimen is a disk with near-uniform edges of 2 pi support_radius / `resolution`
    (a ring mesh, cloth.scenes.garments.uniform_annulus_mesh, around a hole far inside the
    clamp); every node within the support's radius is pinned (the clamp), the rest starts flat
    with a seeded sub-millimetre `jitter` (m) out of plane that picks where the folds form. Every
    frame's record carries the drape measures (cloth.eval.drape: drape_coefficient, hem radius,
    folds)."""
    name = "cusick_drape"
    _check_resolution(name, resolution)
    _check_size(name, specimen_radius=specimen_radius, support_radius=support_radius, height=height)
    if not support_radius < specimen_radius:
        raise SceneError(f"scene {name!r}: support_radius ({support_radius} m) must be below specimen_radius "
                         f"({specimen_radius} m): the specimen drapes over the support's edge")
    if not jitter >= 0:
        raise SceneError(f"scene {name!r}: jitter must be >= 0 m, got {jitter}")
    edge = 2 * np.pi * support_radius / int(resolution)
    hole = min(0.5 * edge, 0.25 * support_radius)
    mesh = uniform_annulus_mesh(hole, specimen_radius - hole, edge, center=(0.0, 0.0, height))
    r = np.linalg.norm(mesh.vert_u, axis=1)
    clamped = np.zeros(mesh.n_nodes, dtype=bool)
    clamped[mesh.vert_node[r <= support_radius * (1 + 1e-9)]] = True
    if jitter > 0:
        noise = jitter * np.random.default_rng(seed).standard_normal(mesh.n_nodes)
        mesh.node_x[~clamped, 2] += noise[~clamped]
    probe = DrapeProbe(center=(0.0, 0.0), support_radius=support_radius, specimen_radius=specimen_radius)
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects), frame_time=frame_time,
                 steps_per_frame=steps_per_frame, handles=[Handle(np.flatnonzero(clamped), Static())],
                 probes=(probe,))


# The paper's stage: rows of five dancers (ten dancers: 5 x 2). A crowd of more than ten gets
# ceil(sqrt(CROWD_ASPECT x dancers)) per row, so that it has about CROWD_ASPECT times as many
# columns as rows, as the paper's 5 x 2 stage has.
