"""Reading an ARCSim config: :func:`load_arcsim_config` (re-exported by :mod:`cloth.io.arcsim`,
whose docstring gives the keys and their semantics) and the readers of its sections. A value
reader takes (value, key, ctx), a section reader (top, ctx, ...); each checks what it reads and
returns :mod:`cloth.io.arcsim_schema` data, or raises ArcsimConfigError naming the key (a JSON
path) and the config file."""

from __future__ import annotations

import math
import re
from pathlib import Path

import numpy as np

from cloth.io.arcsim_json import (
    ArcsimConfigError,
    ConfContext,
    as_bool,
    as_int,
    as_list,
    as_number,
    as_object,
    as_string,
    as_vector,
    check_keys,
    join_key,
    member,
    read_json_with_comments,
)
from cloth.io.arcsim_mesh import read_arcsim_obj
from cloth.io.arcsim_motion import (
    ArcsimMotion,
    Transformation,
    keyframe_velocity,
    mot_motions,
    read_mot,
)
from cloth.io.arcsim_schema import (
    MAGIC_031,
    MAGIC_DEFAULTS,
    MATERIAL_UNSUPPORTED,
    MODULES,
    TRANSFORM_KEYS,
    ArcsimCloth,
    ArcsimConfig,
    ArcsimHandle,
    ArcsimMaterial,
    ArcsimMotfile,
    ArcsimObstacle,
    ArcsimRemeshing,
    ArcsimVelocity,
    ArcsimWind,
)
from cloth.io.obj import ObjError

# ---- reading -------------------------------------------------------------------------------------

def load_arcsim_config(conf_path, root=None) -> ArcsimConfig:
    """Read the ARCSim config at `conf_path` and every file it names (module docstring).

    root: the directory relative file names are resolved against; default the config file's
    parent's parent (``<root>/conf/scene.json``). ArcsimConfigError naming the key and the file
    for anything this reader cannot represent exactly.
    """
    conf_path = Path(conf_path).expanduser().absolute()
    root = Path(root).expanduser().absolute() if root is not None else conf_path.parent.parent
    if not conf_path.is_file():
        raise ArcsimConfigError(f"{conf_path}: no such config file", path=conf_path)
    ctx = ConfContext(conf_path=conf_path, root=root)
    top = read_json_with_comments(conf_path)
    if not isinstance(top, dict):
        raise ctx.error(None, "a config must be a JSON object")
    check_keys(top, "", ctx, supported=(
        "frame_time", "frame_steps", "end_time", "end_frame", "timestep", "save_frames", "duration", "cloths",
        "motions", "handles", "obstacles", "gravity", "wind", "friction", "obs_friction", "disable", "magic"),
        unsupported={"morphs": "morph targets", "passive_time": "0.3.1's passive time (after fracture)",
                     "save_every": "0.3.1's output thinning"},
        renamed={"obstacle_friction": "obs_friction"})
    timing = _timing(top, ctx)
    cloths = _cloths(top, ctx)
    motions, motfile = _motions(top, ctx)
    handles = _handles(top, ctx, cloths, motions)
    obstacles, pattern = _obstacles(top, ctx, motions)
    return ArcsimConfig(
        conf_path=conf_path, root=root, **timing, cloths=cloths, motions=motions, handles=handles,
        obstacles=obstacles,
        gravity=member(top, "gravity", "", ctx, _vector3, default=np.zeros(3)),
        wind=_wind(top, ctx),
        friction=member(top, "friction", "", ctx, _non_negative, default=0.6),
        obs_friction=member(top, "obs_friction", "", ctx, _non_negative, default=0.3),
        disable=_disable(top, ctx), magic=_magic(top, ctx), motfile=motfile, obstacle_pattern=pattern)


# ---- value readers (value, key, ctx) -> value ----------------------------------------------------

def _vector3(value, key, ctx) -> np.ndarray:
    return as_vector(value, key, ctx, 3)


def _non_negative(value, key, ctx) -> float:
    x = as_number(value, key, ctx)
    if x < 0:
        raise ctx.error(key, f"must be >= 0, got {x}")
    return x


def _positive(value, key, ctx) -> float:
    x = as_number(value, key, ctx)
    if not x > 0:
        raise ctx.error(key, f"must be > 0, got {x}")
    return x


def _at_least_one(value, key, ctx) -> int:
    n = as_int(value, key, ctx)
    if n < 1:
        raise ctx.error(key, f"must be >= 1, got {n}")
    return n


def _range(value, key, ctx) -> tuple[float, float]:
    lo, hi = as_vector(value, key, ctx, 2)
    if lo > hi:
        raise ctx.error(key, f"[min, max] with min > max: {[lo, hi]}")
    return float(lo), float(hi)


def _transform_parts(value, key, ctx) -> dict:
    """The translate / rotate / scale of a transform object, checked (rotate: [angle_deg, axis])."""
    obj = as_object(value, key, ctx)
    check_keys(obj, key, ctx, TRANSFORM_KEYS)
    parts = {"translate": member(obj, "translate", key, ctx, _vector3, default=np.zeros(3)),
             "rotate": member(obj, "rotate", key, ctx, lambda v, k, c: as_vector(v, k, c, 4),
                              default=np.array([0.0, 1.0, 0.0, 0.0])),
             "scale": member(obj, "scale", key, ctx, as_number, default=1.0)}
    if parts["rotate"][0] != 0 and not np.any(parts["rotate"][1:]):
        raise ctx.error(join_key(key, "rotate"), "a rotation by a nonzero angle needs a nonzero axis")
    return parts


def _transform(value, key, ctx) -> Transformation:
    """A keyframe's transform: any finite scale (ARCSim animates scale, down to 0 in tshirt.json)."""
    return Transformation.from_config(**_transform_parts(value, key, ctx))


def _placement(value, key, ctx) -> Transformation:
    """A static transform (cloth, obstacle, motfile): scale > 0."""
    tr = _transform(value, key, ctx)
    if not tr.scale > 0:
        raise ctx.error(join_key(key, "scale"), f"must be > 0, got {tr.scale}")
    return tr


# ---- sections ------------------------------------------------------------------------------------

def _timing(top: dict, ctx: ConfContext) -> dict:
    """frame_time, frame_steps, step_time, end_time, end_frame from either timing form."""
    if top.get("frame_time") is not None:
        for other in ("timestep", "save_frames"):
            if top.get(other) is not None:
                raise ctx.error(other, "belongs to the timestep form; this config uses frame_time")
        frame_time = member(top, "frame_time", "", ctx, _positive)
        frame_steps = member(top, "frame_steps", "", ctx, _at_least_one, default=1)
        step_time = frame_time / frame_steps
        if top.get("end_time") is not None and top.get("duration") is not None:
            raise ctx.error("duration", "end_time is given too: give one end time")
        end_time = member(top, "end_time", "", ctx, _positive,
                          default=member(top, "duration", "", ctx, _positive, default=math.inf))
        end_frame = member(top, "end_frame", "", ctx, _non_negative_int)
    elif top.get("timestep") is not None:
        for other in ("frame_steps", "end_time", "end_frame"):
            if top.get(other) is not None:
                raise ctx.error(other, "belongs to the frame_time form; this config uses timestep "
                                       "(ARCSim ignores it there)")
        step_time = member(top, "timestep", "", ctx, _positive)
        frame_steps = member(top, "save_frames", "", ctx, _at_least_one, default=1)
        frame_time = step_time * frame_steps
        end_time = member(top, "duration", "", ctx, _positive, default=math.inf)
        end_frame = None
    else:
        raise ctx.error("frame_time", "is required (or timestep, the other timing form)")
    return dict(frame_time=frame_time, frame_steps=frame_steps, step_time=step_time, end_time=end_time,
                end_frame=end_frame)


def _non_negative_int(value, key, ctx) -> int:
    n = as_int(value, key, ctx)
    if n < 0:
        raise ctx.error(key, f"must be >= 0, got {n}")
    return n


def _cloths(top: dict, ctx: ConfContext) -> tuple[ArcsimCloth, ...]:
    items = member(top, "cloths", "", ctx, as_list, required=True)
    if not items:
        raise ctx.error("cloths", "needs at least one cloth")
    return tuple(_cloth(value, join_key("cloths", i), ctx) for i, value in enumerate(items))


def _cloth(value, key: str, ctx: ConfContext) -> ArcsimCloth:
    obj = as_object(value, key, ctx)
    check_keys(obj, key, ctx, ("mesh", "transform", "velocity", "materials", "remeshing"),
               unsupported={"reference": "0.3.1's reference shapes"})
    mesh_path, mesh = _mesh(obj, key, ctx)
    transform = member(obj, "transform", key, ctx, _placement, default=Transformation.identity())
    velocity = member(obj, "velocity", key, ctx, _velocity,
                      default=ArcsimVelocity(np.zeros(3), np.zeros(3), np.zeros(3)))
    node_x = transform.apply(mesh.node_x)
    node_v = velocity.linear + np.cross(velocity.angular, node_x - velocity.origin)
    materials_key = join_key(key, "materials")
    items = member(obj, "materials", key, ctx, as_list, required=True)
    if len(items) != 1:
        raise ctx.error(materials_key, f"needs exactly one material, found {len(items)} (several materials "
                                       "are assigned by OBJ face labels, which this reader does not support)")
    materials = tuple(_material(v, join_key(materials_key, i), ctx) for i, v in enumerate(items))
    remeshing = member(obj, "remeshing", key, ctx, _remeshing, default=ArcsimRemeshing())
    return ArcsimCloth(mesh=mesh_path, transform=transform, velocity=velocity, materials=materials,
                       remeshing=remeshing, node_x=node_x, node_v=node_v, vert_u=mesh.vert_u * transform.scale,
                       vert_node=mesh.vert_node, face_verts=mesh.face_verts)


def _mesh(obj: dict, key: str, ctx: ConfContext):
    """(path, ArcsimObj) of obj["mesh"]."""
    mesh_key = join_key(key, "mesh")
    path = ctx.existing_file(member(obj, "mesh", key, ctx, as_string, required=True), mesh_key)
    return path, _read_obj(path, mesh_key, ctx)


def _read_obj(path: Path, key: str, ctx: ConfContext):
    try:
        return read_arcsim_obj(path)
    except ObjError as exc:
        raise ctx.error(key, str(exc)) from None


def _velocity(value, key, ctx) -> ArcsimVelocity:
    obj = as_object(value, key, ctx)
    check_keys(obj, key, ctx, ("linear", "angular", "origin"))
    return ArcsimVelocity(*(member(obj, name, key, ctx, _vector3, default=np.zeros(3))
                            for name in ("linear", "angular", "origin")))


def _material(value, key, ctx) -> ArcsimMaterial:
    obj = as_object(value, key, ctx)
    check_keys(obj, key, ctx, ("data", "thicken", "density_mult", "stretching_mult", "bending_mult", "damping",
                               "strain_limits"), unsupported=MATERIAL_UNSUPPORTED)
    data = ctx.existing_file(member(obj, "data", key, ctx, as_string, required=True), join_key(key, "data"))
    factors = {name: member(obj, name, key, ctx, _non_negative, default=1.0)
               for name in ("thicken", "density_mult", "stretching_mult", "bending_mult")}
    strain_min, strain_max = member(obj, "strain_limits", key, ctx, _range, default=(-math.inf, math.inf))
    return ArcsimMaterial(data=data, **factors, damping=member(obj, "damping", key, ctx, _non_negative, default=0.0),
                          strain_min=strain_min, strain_max=strain_max)


def _remeshing(value, key, ctx) -> ArcsimRemeshing:
    obj = as_object(value, key, ctx)
    check_keys(obj, key, ctx, ("refine_angle", "refine_compression", "refine_velocity", "size", "aspect_min"),
               unsupported={"size_uniform": "0.3.1's uniform sizing", "refine_fracture": "0.3.1's fracture"})
    defaults = ArcsimRemeshing()
    size_min, size_max = member(obj, "size", key, ctx, _range, default=(defaults.size_min, defaults.size_max))
    return ArcsimRemeshing(**{name: member(obj, name, key, ctx, _positive, default=getattr(defaults, name))
                              for name in ("refine_angle", "refine_compression", "refine_velocity")},
                           size_min=size_min, size_max=size_max,
                           aspect_min=member(obj, "aspect_min", key, ctx, as_number, default=defaults.aspect_min))


def _motions(top: dict, ctx: ConfContext) -> tuple[tuple[ArcsimMotion, ...], ArcsimMotfile | None]:
    value = top.get("motions")
    if value is None:
        return (), None
    if isinstance(value, dict):
        check_keys(value, "motions", ctx, ("motfile", "fps", "transform"))
        path = ctx.existing_file(member(value, "motfile", "motions", ctx, as_string, required=True),
                                 "motions.motfile")
        source = ArcsimMotfile(path=path, fps=member(value, "fps", "motions", ctx, _positive, required=True),
                               transform=member(value, "transform", "motions", ctx, _placement,
                                                default=Transformation.identity()))
        try:
            mot = read_mot(path)
        except ArcsimConfigError as exc:
            raise ctx.error("motions.motfile", str(exc)) from None
        return tuple(mot_motions(mot, source.fps, source.transform)), source
    items = as_list(value, "motions", ctx)
    return tuple(_motion(v, join_key("motions", i), ctx) for i, v in enumerate(items)), None


def _motion(value, key: str, ctx: ConfContext) -> ArcsimMotion:
    keys = as_list(value, key, ctx)
    if not keys:
        raise ctx.error(key, "a motion needs at least one keyframe")
    times, transforms, velocities = [], [], []
    for i, v in enumerate(keys):
        k = join_key(key, i)
        obj = as_object(v, k, ctx)
        check_keys(obj, k, ctx, ("time", "transform", "velocity"))
        times.append(member(obj, "time", k, ctx, as_number, required=True))
        if i and times[-1] <= times[-2]:
            raise ctx.error(join_key(k, "time"), f"keyframe times must increase strictly: {times[-2]} then {times[-1]}")
        transforms.append(member(obj, "transform", k, ctx, _transform, default=Transformation.identity()))
        velocities.append(member(obj, "velocity", k, ctx, _keyframe_velocity))
    return ArcsimMotion.from_keys(times, transforms, velocities)


def _keyframe_velocity(value, key, ctx) -> np.ndarray:
    """(8,) tangent of a keyframe's velocity object (arcsim_motion.keyframe_velocity: ARCSim's quirks)."""
    return keyframe_velocity(**_transform_parts(value, key, ctx))


def _motion_index(obj: dict, key: str, ctx: ConfContext, motions) -> int | None:
    m = member(obj, "motion", key, ctx, as_int, default=-1)
    if m == -1:
        return None
    if not 0 <= m < len(motions):
        raise ctx.error(join_key(key, "motion"), f"motion {m} does not exist ({len(motions)} motion(s))")
    return m


def _handles(top: dict, ctx: ConfContext, cloths, motions) -> tuple[ArcsimHandle, ...]:
    handles = []
    for i, value in enumerate(member(top, "handles", "", ctx, as_list, default=[])):
        key = join_key("handles", i)
        obj = as_object(value, key, ctx)
        kind = member(obj, "type", key, ctx, as_string, default="node")
        if kind in ("circle", "glue", "soft"):
            raise ctx.error(join_key(key, "type"), f"not supported by this reader: ARCSim's {kind} handles "
                                                   "(node handles only)")
        if kind != "node":
            raise ctx.error(join_key(key, "type"), f"unknown handle type {kind!r} (ARCSim's: node, circle, glue, "
                                                   "soft)")
        check_keys(obj, key, ctx, ("type", "cloth", "nodes", "motion", "start_time", "end_time", "fade_time"),
                   unsupported={"label": "label handles (they need OBJ node labels)"},
                   renamed={"vertices": "nodes"})
        c = member(obj, "cloth", key, ctx, as_int, default=0)
        if not 0 <= c < len(cloths):
            raise ctx.error(join_key(key, "cloth"), f"cloth {c} does not exist ({len(cloths)} cloth(s))")
        nodes_key = join_key(key, "nodes")
        items = member(obj, "nodes", key, ctx, as_list, required=True)
        nodes = np.array([as_int(n, join_key(nodes_key, j), ctx) for j, n in enumerate(items)], dtype=np.int64)
        bad = (nodes < 0) | (nodes >= cloths[c].n_nodes)
        if np.any(bad):
            j = int(np.argmax(bad))
            raise ctx.error(join_key(nodes_key, j), f"node {nodes[j]} does not exist (cloth {c} has "
                                                    f"{cloths[c].n_nodes} nodes)")
        start = member(obj, "start_time", key, ctx, as_number, default=0.0)
        end = member(obj, "end_time", key, ctx, as_number, default=math.inf)
        handles.append(ArcsimHandle(cloth=c, nodes=nodes, motion=_motion_index(obj, key, ctx, motions),
                                    start_time=start, end_time=end,
                                    fade_time=member(obj, "fade_time", key, ctx, _non_negative, default=0.0)))
    return tuple(handles)


# a printf conversion: an integer one (flags, width), a literal %%, or (a lone %) anything else
_PRINTF_FIELD = re.compile(r"%(?:%|[-+ 0#]*\d*[diuoxX])?")


def _obstacles(top: dict, ctx: ConfContext, motions) -> tuple[tuple[ArcsimObstacle, ...], str | None]:
    value = top.get("obstacles")
    if value is None:
        return (), None
    if isinstance(value, str):
        fields = [f for f in _PRINTF_FIELD.findall(value) if f != "%%"]
        if len(fields) != 1 or fields[0] == "%":
            raise ctx.error("obstacles", f"a pattern needs exactly one printf integer field (like %04d), got "
                                         f"{value!r}")
        obstacles = []
        while (ctx.root / (value % len(obstacles))).is_file():
            i = len(obstacles)
            path = ctx.existing_file(value % i, "obstacles")
            mesh = _read_obj(path, "obstacles", ctx)
            obstacles.append(ArcsimObstacle(mesh=path, transform=Transformation.identity(), node_x=mesh.node_x,
                                            face_nodes=mesh.face_nodes, motion=i if i < len(motions) else None))
        if not obstacles:
            raise ctx.error("obstacles", f"no file for pattern {value!r}: {ctx.root / (value % 0)} does not exist")
        return tuple(obstacles), value
    obstacles = []
    for i, item in enumerate(as_list(value, "obstacles", ctx)):
        key = join_key("obstacles", i)
        obj = as_object(item, key, ctx)
        check_keys(obj, key, ctx, ("mesh", "transform", "motion", "start_time", "end_time"),
                   unsupported={"proxy": "0.3.1's proxy obstacles"})
        path, mesh = _mesh(obj, key, ctx)
        transform = member(obj, "transform", key, ctx, _placement, default=Transformation.identity())
        obstacles.append(ArcsimObstacle(
            mesh=path, transform=transform, node_x=transform.apply(mesh.node_x), face_nodes=mesh.face_nodes,
            motion=_motion_index(obj, key, ctx, motions),
            start_time=member(obj, "start_time", key, ctx, as_number, default=0.0),
            end_time=member(obj, "end_time", key, ctx, as_number, default=math.inf)))
    return tuple(obstacles), None


def _wind(top: dict, ctx: ConfContext) -> ArcsimWind:
    obj = member(top, "wind", "", ctx, as_object, default={})
    check_keys(obj, "wind", ctx, ("velocity", "density", "drag"))
    return ArcsimWind(velocity=member(obj, "velocity", "wind", ctx, _vector3, default=np.zeros(3)),
                      density=member(obj, "density", "wind", ctx, _non_negative, default=1.0),
                      drag=member(obj, "drag", "wind", ctx, _non_negative, default=0.0))


def _disable(top: dict, ctx: ConfContext) -> frozenset:
    names = member(top, "disable", "", ctx, as_list, default=[])
    out = set()
    for i, value in enumerate(names):
        key = join_key("disable", i)
        name = as_string(value, key, ctx)
        if name not in MODULES:
            raise ctx.error(key, f"unknown module {name!r} (ARCSim's: {', '.join(sorted(MODULES))})")
        out.add(name)
    return frozenset(out)


def _magic(top: dict, ctx: ConfContext) -> dict:
    obj = member(top, "magic", "", ctx, as_object, default={})
    check_keys(obj, "magic", ctx, (*MAGIC_DEFAULTS, *MAGIC_031))
    readers = {bool: as_bool, int: as_int, float: as_number}
    magic = {}
    for name, default in MAGIC_DEFAULTS.items():
        kind = type(default)
        if name == "projection_thickness":
            default = 0.1 * magic["repulsion_thickness"]
        magic[name] = member(obj, name, "magic", ctx, readers[kind], default=default)
    for name, kind in MAGIC_031.items():
        if obj.get(name) is not None:
            magic[name] = member(obj, name, "magic", ctx, readers[kind])
    return magic
