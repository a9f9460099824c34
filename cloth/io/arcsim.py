"""ARCSim scene configurations (Narain et al. 2012; versions 0.2.1 and 0.3.1) as plain, checked data.

:func:`load_arcsim_config` reads a config (JSON with ``//`` and ``/* */`` comments) and the files
it names, and returns an :class:`ArcsimConfig` of dataclasses and numpy arrays. It builds no
project Scene and knows no Hydra: a scene builder maps this data onto the project's objects. The
semantics below are those of ARCSim's ``conf.cpp``; what ARCSim does with each value is said
where the value is declared. File names are resolved against `root` (ARCSim resolves them
against its working directory, the parent of ``conf/``); every path in the result is absolute and
exists. Material files are only located here (their contents are another module's business).

Nothing is ignored. A key this reader does not know, a key ARCSim knows but this reader does not
support, a value of the wrong type or length, a missing file and an index out of range each raise
:class:`ArcsimConfigError`, whose message (and ``.key``, ``.path``) names the key as a JSON path
(``cloths[0].materials[0].thicken``) and the config file. An explicit ``null`` is an absent key,
as in jsoncpp.

Supported keys (ARCSim's defaults when absent):

* timing, two forms. ``frame_time`` (s, required in this form), ``frame_steps`` (1), ``end_time``
  (inf), ``end_frame`` (none); or ``timestep`` (s), ``save_frames`` (1: steps per frame),
  ``duration`` (inf). ``duration`` is the end time in both forms: ARCSim reads it only in the
  timestep form and ignores it next to ``frame_time`` (flag.json gives both, so ARCSim runs it
  forever); here it ends the run, and giving it together with ``end_time`` is an error. Keys of
  the other form are errors (ARCSim would ignore them).
* ``cloths`` (required, non-empty): ``mesh`` (OBJ, :mod:`cloth.io.arcsim_mesh`), ``transform``
  (identity), ``velocity`` {``linear``, ``angular``, ``origin``} (0: initial node velocity
  v = linear + angular x (x - origin), x after the transform), ``materials`` (required, exactly
  one: several need OBJ face labels), ``remeshing``.
  The transform maps the file positions to world positions, and its *scale also multiplies the
  material coordinates* (ARCSim scales the verts' u before computing rest data).
* ``materials[i]``: ``data`` (required: the material file), ``thicken`` (1), ``density_mult``,
  ``stretching_mult``, ``bending_mult`` (1 each; ARCSim multiplies each by ``thicken`` too),
  ``damping`` (0), ``strain_limits`` [min, max] (none: -inf, inf; as 1 + strain).
* ``remeshing``: ``refine_angle``, ``refine_compression``, ``refine_velocity`` (inf), ``size``
  [min, max] (-inf, inf; metres), ``aspect_min`` (-inf).
* ``motions``: a list of keyframe lists (``time`` required, ``transform`` (identity),
  ``velocity``), or an object {``motfile``, ``fps`` (both required), ``transform``} for the rigid
  parts of a .mot file; interpolation in :mod:`cloth.io.arcsim_motion`.
* ``handles``: node handles only (``type`` "node", the default): ``cloth`` (0), ``nodes``
  (required: node numbers = OBJ ``v`` lines from 0), ``motion`` (none; -1 is none), ``start_time``
  (0), ``end_time`` (inf), ``fade_time`` (0).
* ``obstacles``: a list of {``mesh`` (required), ``transform`` (identity), ``motion`` (none),
  ``start_time`` (0), ``end_time`` (inf)}, or a printf pattern with one integer field: one static-
  shape obstacle per existing file pattern % i, i = 0, 1, ... up to the first missing file, with
  motion i when there is one (none otherwise) and no transform.
* ``gravity`` (0, m/s^2), ``wind`` {``velocity`` (0, m/s), ``density`` (1, kg/m^3), ``drag`` (0)},
  ``friction`` (0.6, cloth-cloth), ``obs_friction`` (0.3, cloth-obstacle), ``disable`` (a list of
  :data:`MODULES` names), ``magic`` (:data:`MAGIC_DEFAULTS`, :data:`MAGIC_031`).

Rejected as unsupported: ``morphs``; plasticity (``yield_curv``, ``weakening`` and 0.3.1's
``yield_stretch``, ``plastic_flow``, ``plastic_limit``); 0.3.1's parametric and fracturing
materials (``thickness``, ``density``, ``elastic_modulus``, ``poisson_ratio``, ``toughness``,
``fracture_bending_mult``), ``reference``, ``size_uniform``, ``refine_fracture``, ``proxy``,
``passive_time``, ``save_every``; circle, glue and soft handles and label handles (``label``);
OBJ extension lines (labels, velocities, edges; :data:`cloth.io.arcsim_mesh.ARCSIM_OBJ_EXTENSIONS`).
``obstacle_friction`` is an error pointing at ``obs_friction`` (neither version reads it).

ARCSim 0.2.1's 17 example configs: crush, crush2, dress-blue, dress-yellow, flag, sleeve, sphere,
square and square-pop load; crumple, crumple-pnas and tshirt fail on plasticity (``yield_curv``),
cylinder and fold on node labels in their meshes (and circle handles, plasticity), dart on OBJ
edges (and plasticity), karate on its empty .mot file in the public snapshot (it loads with a
readable one), sphere-annotated on ``handles[0].vertices`` (ARCSim reads ``nodes``: ARCSim itself
aborts on that file). Of 0.3.1's: flag, sphere, square and square-pop load; paper-tearing and
sphere-break fail on ``remeshing_frames`` (read by neither version).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass, field
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
from cloth.io.obj import ObjError

__all__ = [
    "ArcsimCloth", "ArcsimConfig", "ArcsimConfigError", "ArcsimHandle", "ArcsimMaterial", "ArcsimMotfile",
    "ArcsimMotion", "ArcsimObstacle", "ArcsimRemeshing", "ArcsimVelocity", "ArcsimWind", "MAGIC_031",
    "MAGIC_DEFAULTS", "MODULES", "Transformation", "load_arcsim_config",
]

# The simulation modules a config may ``disable`` (0.2.1's eight, and 0.3.1's fracture).
MODULES = frozenset({"proximity", "physics", "strainlimiting", "collision", "remeshing", "separation",
                     "popfilter", "plasticity", "fracture"})

# ARCSim 0.2.1's magic numbers and their defaults (magic.hpp). ``projection_thickness`` defaults
# to 0.1 x the (possibly configured) ``repulsion_thickness``, as conf.cpp reads it.
MAGIC_DEFAULTS = {
    "fixed_high_res_mesh": False,  # bool
    "handle_stiffness": 1e3,  # N/m: a handle constraint's energy is stiffness x strength x distance^2 / 2
    "collision_stiffness": 1e9,  # of the repulsion penalty (its energy also divides by repulsion_thickness)
    "repulsion_thickness": 1e-3,  # m
    "projection_thickness": 1e-4,  # m
    "edge_flip_threshold": 1e-2,
    "rib_stiffening": 1.0,
    "combine_tensors": True,  # bool
    "preserve_creases": False,  # bool
}
# Magic numbers only 0.3.1 reads -> their type; in ArcsimConfig.magic only when the config sets them.
MAGIC_031 = {"add_jitter": bool, "separation_step_size": float, "relax_method": int, "max_cracks": int,
             "enable_localopt": bool}

TRANSFORM_KEYS = ("translate", "rotate", "scale")

_PLASTICITY = "plasticity (ARCSim's plastic/yield model)"
_MATERIAL_UNSUPPORTED = {
    "yield_curv": _PLASTICITY, "weakening": _PLASTICITY, "yield_stretch": _PLASTICITY + ", 0.3.1",
    "plastic_flow": _PLASTICITY + ", 0.3.1", "plastic_limit": _PLASTICITY + ", 0.3.1",
    **{k: "0.3.1's parametric (non-data) materials" for k in
       ("thickness", "density", "elastic_modulus", "poisson_ratio")},
    "toughness": "0.3.1's fracture", "fracture_bending_mult": "0.3.1's fracture",
}


# ---- the data ------------------------------------------------------------------------------------

@dataclass(frozen=True)
class ArcsimMaterial:
    """One entry of a cloth's ``materials`` (the file's contents are read elsewhere). ARCSim
    multiplies the file's density by :attr:`density_factor`, its stretching samples by
    :attr:`stretching_factor` and its bending data by :attr:`bending_factor`."""

    data: Path  # the material file (absolute, exists)
    thicken: float = 1.0  # multiplies all three factors below
    density_mult: float = 1.0
    stretching_mult: float = 1.0
    bending_mult: float = 1.0
    damping: float = 0.0  # s: stiffness-proportional (Rayleigh) damping coefficient
    strain_min: float = -math.inf  # strain limits, as principal stretch (1 + strain); +-inf: none
    strain_max: float = math.inf

    @property
    def density_factor(self) -> float:
        return self.density_mult * self.thicken

    @property
    def stretching_factor(self) -> float:
        return self.stretching_mult * self.thicken

    @property
    def bending_factor(self) -> float:
        return self.bending_mult * self.thicken

    @property
    def strain_limited(self) -> bool:
        """Whether ARCSim's strain limiting acts on this material (a finite limit)."""
        return math.isfinite(self.strain_min) or math.isfinite(self.strain_max)


@dataclass(frozen=True)
class ArcsimRemeshing:
    """A cloth's ``remeshing`` parameters (Narain et al. 2012, section 3); inf / -inf: no limit."""

    refine_angle: float = math.inf  # rad: bound on the change of normals across an element
    refine_compression: float = math.inf  # bound on compression (buckling anticipation)
    refine_velocity: float = math.inf  # bound on the change of velocity across an element (relative)
    size_min: float = -math.inf  # m: edge length bounds
    size_max: float = math.inf
    aspect_min: float = -math.inf  # lower bound on triangle aspect ratio


@dataclass(frozen=True, eq=False)
class ArcsimVelocity:
    """A cloth's initial ``velocity``: node velocity v = linear + angular x (x - origin)."""

    linear: np.ndarray  # (3,) float64, m/s
    angular: np.ndarray  # (3,) float64, rad/s
    origin: np.ndarray  # (3,) float64, m (world)


@dataclass(frozen=True, eq=False)
class ArcsimCloth:
    """One entry of ``cloths``: the mesh after its transform, and its parameters.

    Node numbers are the OBJ file's ``v`` lines from 0 (what handles name); verts and triangles
    are as :mod:`cloth.io.arcsim_mesh` builds them (triangles in the file's winding).
    """

    mesh: Path  # the OBJ file (absolute, exists)
    transform: Transformation  # file positions -> world positions; its scale also scales vert_u
    velocity: ArcsimVelocity
    materials: tuple[ArcsimMaterial, ...]  # one entry (every face uses material 0)
    remeshing: ArcsimRemeshing
    # --- world space (the initial state) ---
    node_x: np.ndarray  # (n_nodes, 3) float64, m: transform applied to the file positions
    node_v: np.ndarray  # (n_nodes, 3) float64, m/s: from `velocity`
    # --- material space ---
    vert_u: np.ndarray  # (n_verts, 2) float64, m: material coordinates x transform.scale
    # --- topology ---
    vert_node: np.ndarray  # (n_verts,) int64
    face_verts: np.ndarray  # (n_faces, 3) int64

    @property
    def n_nodes(self) -> int:
        return self.node_x.shape[0]


@dataclass(frozen=True, eq=False)
class ArcsimHandle:
    """A node handle: `nodes` of cloth `cloth` held by motion `motion` (fixed where they are when
    it is None) while active.

    ARCSim semantics, for the builder: the handle attaches each node when its strength first
    becomes nonzero (at ``start_time``), at the node's position *then*: target(t) =
    motions[motion].carry(x(start_time), start_time, t) (T(t) T(start_time)^-1 x), or x(start_time)
    without a motion. Its constraint stiffness is magic ``handle_stiffness`` x :meth:`strength`.
    ARCSim also marks the nodes "preserve" (the remesher never removes them).
    """

    cloth: int  # index into ArcsimConfig.cloths
    nodes: np.ndarray  # (k,) int64: node numbers of that cloth
    motion: int | None  # index into ArcsimConfig.motions, None: fixed
    start_time: float = 0.0  # s
    end_time: float = math.inf  # s
    fade_time: float = 0.0  # s: after end_time the strength fades to 0 over this time

    def strength(self, t: float) -> float:
        """ARCSim's Handle::strength: 1 on [start, end], (1 - (t - end)/(fade + 1e-6))^4 on
        (end, end + fade], 0 elsewhere."""
        if t < self.start_time or t > self.end_time + self.fade_time:
            return 0.0
        if t <= self.end_time:
            return 1.0
        return (1.0 - (t - self.end_time) / (self.fade_time + 1e-6)) ** 4


@dataclass(frozen=True, eq=False)
class ArcsimObstacle:
    """A rigid obstacle: its vertices after its static transform, moved by motion `motion`.

    World vertices at time t: motions[motion].transform_at(t).apply(node_x) (node_x itself without
    a motion). With the project's rigid protocol, scale node_x by motions[motion].scale first.
    ARCSim holds the obstacle only while start_time <= t <= end_time (removed after end_time).
    """

    mesh: Path  # the OBJ file (absolute, exists)
    transform: Transformation  # file positions -> node_x (identity for a pattern's obstacles)
    node_x: np.ndarray  # (n_nodes, 3) float64, m
    face_nodes: np.ndarray  # (n_faces, 3) int64
    motion: int | None  # index into ArcsimConfig.motions, None: static
    start_time: float = 0.0  # s
    end_time: float = math.inf  # s


@dataclass(frozen=True, eq=False)
class ArcsimWind:
    """ARCSim's air: per face of area a and normal n, with relative velocity w = velocity - v_face
    and w_n = n . w, force = density a |w_n| w_n n + drag a (w - w_n n)."""

    velocity: np.ndarray  # (3,) float64, m/s
    density: float = 1.0  # kg/m^3 (0: vacuum)
    drag: float = 0.0  # kg/(m^2 s): tangential drag coefficient


@dataclass(frozen=True)
class ArcsimMotfile:
    """Where ``motions`` came from when it names a .mot file."""

    path: Path  # the .mot file (absolute, exists)
    fps: float  # keyframes per second
    transform: Transformation  # applied on the left of every keyframe


@dataclass(frozen=True, eq=False)
class ArcsimConfig:
    """A whole ARCSim config (module docstring for the keys and their defaults)."""

    conf_path: Path  # the config file (absolute)
    root: Path  # the directory relative file names were resolved against
    # --- timing ---
    frame_time: float  # s per output frame
    frame_steps: int  # time steps per frame
    step_time: float  # s per step (frame_time / frame_steps, or timestep)
    end_time: float  # s, inf: none
    end_frame: int | None  # None: none
    # --- the scene ---
    cloths: tuple[ArcsimCloth, ...]
    motions: tuple[ArcsimMotion, ...]
    handles: tuple[ArcsimHandle, ...]
    obstacles: tuple[ArcsimObstacle, ...]
    gravity: np.ndarray  # (3,) float64, m/s^2
    wind: ArcsimWind
    friction: float  # cloth-cloth Coulomb coefficient
    obs_friction: float  # cloth-obstacle Coulomb coefficient
    disable: frozenset  # module names as written in the config (MODULES)
    magic: dict = field(default_factory=dict)  # MAGIC_DEFAULTS keys (always) and MAGIC_031 keys (when set)
    motfile: ArcsimMotfile | None = None  # set when motions came from a .mot file
    obstacle_pattern: str | None = None  # set when obstacles came from a printf pattern

    @property
    def disabled_modules(self) -> frozenset:
        """The modules ARCSim leaves off: `disable`, plus strain limiting when no material has a
        finite strain limit, plus plasticity and fracture (no supported material has a yield
        curvature or a toughness)."""
        off = set(self.disable) | {"plasticity", "fracture"}
        if not any(m.strain_limited for c in self.cloths for m in c.materials):
            off.add("strainlimiting")
        return frozenset(off)


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
                               "strain_limits"), unsupported=_MATERIAL_UNSUPPORTED)
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
