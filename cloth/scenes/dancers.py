"""The paper's character scenes: solo_dancer and karate (a mannequin, its motion, its garments
and its collision body). A crowd of dancers is cloth.scenes.crowd."""

from __future__ import annotations

import numpy as np

from cloth.core.material import Material
from cloth.core.mesh import MeshError
from cloth.core.scene import Handle, Scene, SceneError
from cloth.eval.drape import DrapeProbe
from cloth.scenes.bodies import skinned_mannequin_mesh
from cloth.scenes.character import JOINTS, Dance, Karate, Mannequin
from cloth.scenes.common import _check_resolution, _check_size
from cloth.scenes.garments import circle_skirt, merge_garments, obj_garment, tube_skirt

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


def solo_dancer(material: Material, *, resolution: int = 31, waist_radius: float = 0.18, skirt_length: float = 0.55,
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


def karate(material: Material, *, resolution: int = 36, inner_radius: float = 0.26, inner_length: float = 0.55,
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
