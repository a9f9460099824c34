"""The data an ARCSim config becomes (:func:`cloth.io.arcsim.load_arcsim_config`): the
modules a config may disable, ARCSim's magic numbers and their defaults, the material keys this
project does not support, and one frozen dataclass per section (cloth, material, remeshing,
handle, obstacle, wind, motion file) and for the whole config. Plain data: numpy arrays and
absolute paths, no project Scene. The keys' semantics are in :mod:`cloth.io.arcsim`'s docstring."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cloth.io.arcsim_motion import (
    ArcsimMotion,
    Transformation,
)

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
MATERIAL_UNSUPPORTED = {
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
