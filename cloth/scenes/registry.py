"""Procedural scenes: hanging_sheet, sheet_on_sphere, flag, and the paper's character scenes
solo_dancer, karate and multiple_dancers (a crowd: one Scene per character).

Each builder takes plain parameters (no Hydra) and returns a :class:`cloth.core.scene.Scene`.
World axes: z up, metres. `resolution` is the number of grid cells along the sheet's longer
side, so a square sheet has 2 * resolution^2 faces.
"""

from __future__ import annotations

import inspect
import math

import numpy as np

from cloth.collision.meshobstacle import MeshObstacleError, TriangleMeshObstacle
from cloth.collision.obstacles import Plane, Ramp, Sphere, Static
from cloth.core.material import Material
from cloth.core.mesh import MeshError, grid_mesh, merge_meshes
from cloth.core.scene import Handle, Scene, SceneError, Wind
from cloth.eval.drape import DrapeProbe
from cloth.io.obj import ObjError, load_obj_sequence
from cloth.scenes.arcsim import arcsim_scene
from cloth.scenes.bodies import moving_sphere_keyframes, skinned_mannequin_mesh
from cloth.scenes.character import JOINTS, Dance, Karate, Mannequin
from cloth.scenes.garments import circle_skirt, merge_garments, obj_garment, tube_skirt, uniform_annulus_mesh


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
    obstacles = [Plane(point=(0.0, 0.0, 0.0), normal=(0.0, 0.0, 1.0)),
                 Sphere(center=(0.0, 0.0, sphere_radius), radius=sphere_radius)]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=obstacles, thickness=thickness, friction=friction)


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


CHARACTER_EFFECTS = ("membrane", "bending", "gravity", "damping", "obstacles")
# m, standard deviation of the seeded noise on a garment's free nodes at the start (each axis):
# far below the contact thickness (5 mm) and the edges (cm), it only makes seeds differ.
CHARACTER_JITTER = 1e-4


def _character_scene(name, material, body, garments, *, thickness, friction, frame_time, steps_per_frame,
                     effects, jitter, seed, notes=(), obstacle=None, probes=()) -> Scene:
    """`obstacle`: what the cloth collides with, if not the capsule `body` (a mesh body).
    `jitter` (m): standard deviation of the seeded noise added to the free garment nodes' initial
    positions (each axis), so that two seeds give two trajectories; the pinned nodes stay."""
    if not jitter >= 0:
        raise SceneError(f"scene {name!r}: jitter must be >= 0 m, got {jitter}")
    mesh, pins = merge_garments(garments)
    if jitter > 0:
        noise = jitter * np.random.default_rng(seed).standard_normal(mesh.node_x.shape)
        noise[np.concatenate(pins)] = 0.0
        mesh.node_x += noise
    handles = [Handle(p, g.motion) for p, g in zip(pins, garments)]
    return Scene(name=name, mesh=mesh, material=material, effects=frozenset(effects),
                 frame_time=frame_time, steps_per_frame=steps_per_frame,
                 obstacles=[obstacle if obstacle is not None else body] if "obstacles" in effects
                 else [], handles=handles, thickness=thickness, friction=friction, notes=tuple(notes),
                 probes=tuple(probes))


BODIES = ("capsules", "mesh")  # the character's collision body: its capsules, or a tessellated skinned mesh of them


def _body_obstacle(name: str, body, kind: str, segments: int):
    """The obstacle of a character scene: the capsule `body` itself, or (kind 'mesh') the same
    capsules as a triangle mesh skinned to the joints (cloth.scenes.bodies.skinned_mannequin_mesh)."""
    if kind not in BODIES:
        raise SceneError(f"scene {name!r}: body must be one of {list(BODIES)}, got {kind!r}")
    if kind == "capsules":
        return None
    if int(segments) < 3:
        raise SceneError(f"scene {name!r}: body_segments must be >= 3, got {segments}")
    return skinned_mannequin_mesh(body, segments=int(segments), name="mannequin_mesh")


DANCER_GARMENTS = ("circle_skirt", "obj")  # solo_dancer's garment: the procedural circle skirt, or an OBJ file's


def _check_phase(name: str, phase: float) -> None:
    if not phase >= 0:
        raise SceneError(f"scene {name!r}: phase is a delay of the motion's start and must be >= 0 s, got {phase}")


def _dancer_garment(name: str, body, garment: str, resolution: int, waist_radius: float, skirt_length: float,
                    obj: dict, cell_aspect: float = 1.0):
    """solo_dancer's garment on `body`: the circle skirt, or (garment 'obj') the garment of the
    OBJ file obj['garment_obj'] (cloth.scenes.garments.obj_garment with the other garment_* keys)."""
    if garment not in DANCER_GARMENTS:
        raise SceneError(f"scene {name!r}: garment must be one of {list(DANCER_GARMENTS)}, got {garment!r}")
    path = obj["garment_obj"]
    if garment == "circle_skirt":
        if path is not None:
            raise SceneError(f"scene {name!r}: garment_obj ({path}) is only read with garment=obj, "
                             f"got garment={garment!r}")
        if not (isinstance(cell_aspect, (int, float)) and cell_aspect >= 1):
            raise SceneError(f"scene {name!r}: cell_aspect must be >= 1, got {cell_aspect!r}")
        return circle_skirt(body, waist_radius=waist_radius, length=skirt_length, resolution=max(int(resolution), 3),
                            cell_aspect=float(cell_aspect))
    if path is None or not str(path).strip():
        raise SceneError(f"scene {name!r}: garment_obj: garment=obj needs the path of an OBJ file with "
                         "texture coordinates")
    for key in ("garment_scale", "garment_uv_scale"):
        if not (isinstance(obj[key], (int, float)) and obj[key] > 0):
            raise SceneError(f"scene {name!r}: {key} must be > 0, got {obj[key]!r}")
    if not (isinstance(obj["garment_pin_distance"], (int, float)) and obj["garment_pin_distance"] >= 0):
        raise SceneError(f"scene {name!r}: garment_pin_distance must be >= 0 m, got {obj['garment_pin_distance']!r}")
    if np.shape(obj["garment_offset"]) != (3,):
        raise SceneError(f"scene {name!r}: garment_offset must be three numbers (m), got {obj['garment_offset']!r}")
    if obj["garment_joint"] not in JOINTS:
        raise SceneError(f"scene {name!r}: garment_joint must be a joint of the mannequin {list(JOINTS)}, "
                         f"got {obj['garment_joint']!r}")
    try:
        return obj_garment(body, path, scale=float(obj["garment_scale"]), offset=tuple(obj["garment_offset"]),
                           uv_scale=float(obj["garment_uv_scale"]), joint=obj["garment_joint"],
                           pin_distance=float(obj["garment_pin_distance"]))
    except MeshError as exc:  # cloth.io.obj.ObjError among them: the message starts with the file
        raise SceneError(f"scene {name!r}: garment_obj: {exc}") from None


def solo_dancer(material: Material, *, resolution: int = 48, waist_radius: float = 0.18, skirt_length: float = 0.55,
                speed: float = 1.0, spin_hz: float = 1.0, settle: float = 0.5, blend_in: float = 1.0,
                position=(0.0, 0.0, 0.0), heading: float = 0.0, phase: float = 0.0,
                thickness: float = 0.005, friction: float = 0.3, frame_time: float = 0.04,
                steps_per_frame: int = 8, seed: int = 0, jitter: float = CHARACTER_JITTER,
                effects=CHARACTER_EFFECTS, body: str = "capsules",
                body_segments: int = 12, garment: str = "circle_skirt", garment_obj=None, garment_scale: float = 1.0,
                garment_offset=(0.0, 0.0, 0.0), garment_uv_scale: float = 1.0, garment_joint: str = "abdomen",
                garment_pin_distance: float = 0.0, cell_aspect: float = 1.0, hem_probe: bool = False) -> Scene:
    """A dancer (the mannequin's `dance` motion) in a circle skirt pinned at the waist, which
    falls from a flat disc, drapes while the dancer stands, then flares out in the turns.
    `resolution`: segments around the waist; `phase` (s, >= 0) delays the motion's start (the
    dancer stands at rest in the opening pose until then), `heading` (rad) and `position` (m)
    place the dancer on the stage. `body`: 'capsules' (analytic) or 'mesh' (the capsules
    tessellated with `body_segments` around each, skinned to the joints).
    `garment`: 'circle_skirt' (`resolution`, `waist_radius`, `skirt_length`) or 'obj': the OBJ
    file `garment_obj` (positions x `garment_scale` + `garment_offset` m, in the dancer's frame;
    texture coordinates x `garment_uv_scale` m per UV unit as material coordinates), pinned to
    `garment_joint` along its boundary loop nearest to that joint, plus the nodes within
    `garment_pin_distance` m of the loop (cloth.scenes.garments.obj_garment); `resolution` is then unused.
    `cell_aspect` > 1: the circle skirt's cells that many times longer across than around (thin input triangles).
    `hem_probe`: every frame's record carries the circle skirt's drape measures about the waist's
    axis (cloth.eval.drape.DrapeProbe with the waist as the support: the hem's radius and folds, the
    skirt's shadow as a drape coefficient), for the dancer standing still (a `settle` longer than
    the run)."""
    name = "solo_dancer"
    if hem_probe and garment != "circle_skirt":
        raise SceneError(f"scene {name!r}: hem_probe measures a circle skirt's hem; garment is {garment!r}")
    _check_resolution(name, resolution)
    _check_size(name, waist_radius=waist_radius, skirt_length=skirt_length, speed=speed)
    _check_phase(name, phase)
    body_kind = body
    body = Mannequin(Dance(speed=speed, spin_hz=spin_hz, settle=settle, blend_in=blend_in),
                     position=position, heading=heading, phase=phase)
    obj = dict(garment_obj=garment_obj, garment_scale=garment_scale, garment_offset=garment_offset,
               garment_uv_scale=garment_uv_scale, garment_joint=garment_joint,
               garment_pin_distance=garment_pin_distance)
    skirt = _dancer_garment(name, body, garment, resolution, waist_radius, skirt_length, obj, cell_aspect)
    obstacle = _body_obstacle(name, body, body_kind, body_segments)
    probes = ()
    if hem_probe:
        waist = skirt.mesh.node_x[np.asarray(skirt.pinned)].mean(axis=0)
        probes = (DrapeProbe(center=(float(waist[0]), float(waist[1])), support_radius=waist_radius,
                             specimen_radius=waist_radius + skirt_length),)
    return _character_scene(name, material, body, [skirt], thickness=thickness, friction=friction,
                            frame_time=frame_time, steps_per_frame=steps_per_frame, effects=effects,
                            jitter=jitter, seed=seed, obstacle=obstacle, probes=probes)


NO_SELF_COLLISION_NOTE = ("karate: the scene does not declare self_collision, so the two skirts pass through "
                          "each other where they touch")


def karate(material: Material, *, resolution: int = 48, inner_radius: float = 0.26, inner_length: float = 0.55,
           outer_radius: float = 0.29, outer_length: float = 0.35, outer_waist_height: float = 0.09,
           speed: float = 1.0, settle: float = 0.5,
           blend_in: float = 1.0, position=(0.0, 0.0, 0.0), heading: float = 0.0, phase: float = 0.0,
           thickness: float = 0.005, friction: float = 0.3, frame_time: float = 0.04, steps_per_frame: int = 8,
           seed: int = 0, jitter: float = CHARACTER_JITTER, effects=CHARACTER_EFFECTS + ("self_collision",),
           body: str = "capsules",
           body_segments: int = 12) -> Scene:
    """A karateka (opening pose with the fists forward, stance, punches, a front kick, a half
    turn) in a layered outfit: a long wide skirt (hakama, a tube with a seam at the back) pinned at
    the hips under a shorter, wider overskirt (also a tube with a seam) pinned `outer_waist_height`
    higher: the layers overlap in height and touch when they swing (cloth-cloth contact through
    the self_collision effect; without it the run notes that they pass through each other).
    `resolution`: segments around each garment; `body`, `body_segments`, `phase` (a delay, s) as in
    solo_dancer."""
    name = "karate"
    _check_resolution(name, resolution)
    _check_size(name, inner_radius=inner_radius, inner_length=inner_length, outer_radius=outer_radius,
                outer_length=outer_length, speed=speed)
    if outer_radius <= inner_radius:
        raise SceneError(f"scene {name!r}: outer_radius ({outer_radius} m) must exceed inner_radius "
                         f"({inner_radius} m): the overskirt is the outer layer")
    _check_phase(name, phase)
    body_kind = body
    body = Mannequin(Karate(speed=speed, settle=settle, blend_in=blend_in), position=position, heading=heading,
                     phase=phase)
    obstacle = _body_obstacle(name, body, body_kind, body_segments)
    n = max(int(resolution), 3)
    # the overskirt has proportionally more segments around: both skirts have the same edge length
    n_outer = max(round(n * outer_radius / inner_radius), 3)
    garments = [tube_skirt(body, waist_radius=inner_radius, length=inner_length, resolution=n, waist_height=0.06),
                tube_skirt(body, waist_radius=outer_radius, length=outer_length, resolution=n_outer,
                           waist_height=outer_waist_height)]
    notes = [] if "self_collision" in effects else [NO_SELF_COLLISION_NOTE]
    return _character_scene(name, material, body, garments, thickness=thickness, friction=friction,
                            frame_time=frame_time, steps_per_frame=steps_per_frame, effects=effects,
                            jitter=jitter, seed=seed, notes=notes, obstacle=obstacle)


def cusick_drape(material: Material, *, resolution: int = 24, specimen_radius: float = 0.15,
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
PAPER_COLUMNS = 5
PAPER_CROWD = 10
CROWD_ASPECT = 2.5


def crowd_columns(dancers: int, columns: int | None = None) -> int:
    """Dancers per row of a crowd of `dancers`: `columns` when given; else (auto) the paper's 5 up
    to 10 dancers (one row, or the paper's 5 x 2), and beyond ceil(sqrt(2.5 dancers)), the least c
    with c^2 >= 2.5 dancers (exact integer arithmetic): 16 per row for 100 dancers (7 rows), 50
    for 1000 (20 rows)."""
    if columns is not None:
        return int(columns)
    n = int(dancers)
    if n <= PAPER_CROWD:
        return PAPER_COLUMNS
    c = math.isqrt(5 * n // 2)
    while 2 * c * c < 5 * n:  # c^2 >= 2.5 n
        c += 1
    return c


def crowd_placement(dancers: int, spacing: float, columns: int | None, phase_step: float, heading_step: float,
                    phase_wrap: float = 1.0):
    """(positions (dancers, 3) m, phases (dancers,) s, headings (dancers,) rad) of a crowd on a
    stage: rows of `columns` dancers (None: :func:`crowd_columns`) `spacing` metres apart,
    centred on the origin, rows behind each other (+y; row 0, the front row, nearest -y) and a
    last row that may be short. Dancer i's phase, the delay of its motion's start, is
    (i * `phase_step`) mod `phase_wrap` seconds (in [0, phase_wrap): every dancer dances for
    most of the run), its heading i * `heading_step` radians."""
    n = int(dancers)
    columns = crowd_columns(n, columns)
    i = np.arange(n)
    col, row = i % columns, i // columns
    n_rows = (n + columns - 1) // columns
    x = (col - (min(n, columns) - 1) / 2) * spacing
    y = (row - (n_rows - 1) / 2) * spacing
    return np.column_stack([x, y, np.zeros(len(i))]), np.mod(i * phase_step, phase_wrap), i * heading_step


def multiple_dancers(material: Material, *, character: int = 0, dancers: int = PAPER_CROWD, spacing: float = 3.0,
                     columns: int | None = None, phase_step: float = 0.37, phase_wrap: float = 1.0,
                     heading_step: float = 0.6, **dancer) -> Scene:
    """Character `character` of a crowd of `dancers` on a stage (the paper's ten dancers):
    exactly `solo_dancer` placed at its spot, with its own phase and heading so the crowd is not
    in lock-step: `spacing` m apart in rows of `columns` (None: auto, :func:`crowd_columns`),
    dancer i's motion starting (i `phase_step`) mod `phase_wrap` seconds late (each stands at
    rest until then) and turned i `heading_step` rad. A crowd run simulates every character as
    its own Simulation (see experiments/run.py); `crowd_size(params)` gives the number of dancers."""
    name = "multiple_dancers"
    if isinstance(dancers, bool) or int(dancers) != dancers or int(dancers) < 1:
        raise SceneError(f"scene {name!r}: dancers must be an integer >= 1, got {dancers!r}")
    if columns is not None and (isinstance(columns, bool) or int(columns) != columns or int(columns) < 1):
        raise SceneError(f"scene {name!r}: columns must be an integer >= 1 or None (auto), got {columns!r}")
    if not 0 <= int(character) < int(dancers):
        raise SceneError(f"scene {name!r}: character must be in [0, {int(dancers) - 1}], got {character}")
    _check_size(name, spacing=spacing)
    if not (phase_step >= 0 and phase_wrap > 0):
        raise SceneError(f"scene {name!r}: phase_step must be >= 0 s and phase_wrap > 0 s, got {phase_step}, "
                         f"{phase_wrap}")
    for key in ("position", "phase", "heading"):
        if key in dancer:
            raise SceneError(f"scene {name!r}: {key} is set per character by the crowd layout")
    pos, phases, headings = crowd_placement(dancers, spacing, columns, phase_step, heading_step, phase_wrap)
    k = int(character)
    scene = solo_dancer(material, position=tuple(pos[k]), phase=float(phases[k]), heading=float(headings[k]),
                        **dancer)
    scene.name = f"{name}/dancer_{k:02d}"
    return scene


CROWDS = {"multiple_dancers"}  # scenes whose builder makes one character of a crowd (parameter `character`)

SCENES = {"hanging_sheet": hanging_sheet, "sheet_on_sphere": sheet_on_sphere, "flag": flag,
          "solo_dancer": solo_dancer, "karate": karate, "multiple_dancers": multiple_dancers,
          "layered_sheets": layered_sheets, "crushed_sheet": crushed_sheet, "mesh_obstacle": mesh_obstacle,
          "cusick_drape": cusick_drape, "arcsim": arcsim_scene}


def build_scene(name: str, material: Material, **params) -> Scene:
    """Build a registered scene by name; unknown names and parameters raise SceneError."""
    if name not in SCENES:
        raise SceneError(f"unknown scene {name!r}; known scenes: {sorted(SCENES)}")
    builder = SCENES[name]
    allowed = {p for p in inspect.signature(builder).parameters if p not in ("material", "dancer")}
    if name in CROWDS:
        allowed |= {p for p in inspect.signature(solo_dancer).parameters
                    if p not in ("material", "position", "phase", "heading")}
    unknown = set(params) - allowed
    if unknown:
        raise SceneError(f"scene {name!r}: unknown parameter(s) {sorted(unknown)}; allowed: {sorted(allowed)}")
    return builder(material, **params)
