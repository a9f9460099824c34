"""ARCSim's scenes (Narain et al. 2012) as project scenes: ``scene=arcsim scene.params.conf=PATH.json``.

:func:`arcsim_scene` reads an ARCSim 0.2.1 / 0.3.1 configuration with :mod:`cloth.io.arcsim`
(which checks every key and file) and maps it onto a :class:`cloth.core.scene.Scene`:

* **cloth**: the OBJ's world positions (after the cloth's transform), material coordinates from
  its ``vt`` (scaled as ARCSim scales them) and initial velocities; the measured material of its
  ``materials`` entry (:func:`cloth.core.measured.load_arcsim_material`: ``thicken`` and the
  multipliers applied as ARCSim applies them, ``damping`` as stiffness-proportional damping,
  ``strain_limits`` as the ``strain_limiting`` effect). Several cloths are merged into one mesh
  when they share one material entry; otherwise the run stops naming ``cloths``.
* **handles**: each node of a node handle is a project :class:`~cloth.core.scene.Handle` of its
  own (a node the remesher puts between two of them stays free, as in ARCSim). It takes hold at
  its ``start_time`` where its node is then and follows its motion relative to that pose
  (ARCSim's attachment at the handle's start); it pins the node until ``end_time``, then for
  ``fade_time`` pulls it with a spring of magic ``handle_stiffness`` x ARCSim's fading strength;
  before ``start_time`` the node is free but kept by the remesher. A motion that scales is refused.
* **obstacles**: all of them are one triangle-mesh obstacle (a union of closed components, as
  the parts of ARCSim's dancing body are) whose vertices follow each part's motion, evaluated
  as ARCSim evaluates it (Hermite keyframes, .mot files), scale included; its velocities are
  the central differences of those positions. Obstacles with start or end times are refused.
  A fast obstacle gets substeps (:data:`OBSTACLE_STEP`: at most half the contact thickness of
  obstacle motion per step), so a frame may take more steps than the conf's ``frame_steps``.
* **effects** (what the scene does not ask for costs nothing): membrane and bending; gravity
  when it is not zero; wind (ARCSim's air: quadratic normal pressure of its density and a
  tangential drag, :class:`~cloth.core.scene.Wind`) when the air has a density, a drag or a
  velocity; damping when the material has some; obstacles when there are any; self_collision
  unless ``disable`` lists ``collision`` or ``proximity``; strain_limiting when a material has
  limits and ``disable`` does not list ``strainlimiting``. Listing effects in the scene config
  (``scene.effects``) keeps only those of them, e.g. a run without self-collision; an effect
  the conf does not call for is refused.
* ``friction`` is the cloth-cloth coefficient, ``obs_friction`` the cloth-obstacle one; magic
  ``repulsion_thickness`` is the thickness kept from obstacles, ``projection_thickness`` (ARCSim's
  hard collision layer, 0.1 x the repulsion thickness unless given) the one kept between cloth
  layers. ARCSim keeps its repulsion thickness with a penalty, which a tight fold can overcome;
  here contacts are exact, and 5 mm held between the sides of a fold on ARCSim's own 5 mm
  elements stretched the cloth there to Green strains of 3. Magic numbers without a counterpart
  here are said in the scene's notes when the conf changes them from ARCSim's defaults
  (``collision_stiffness`` and ``handle_stiffness`` outside a handle's fade: contacts and pinned
  handles are exact constraints here, with no penalty stiffness), and refused when they
  ask for something this tool does not do (``rib_stiffening`` other than 1, ``preserve_creases``,
  ``fixed_high_res_mesh``). Disabling ``physics`` is refused; ``remeshing`` and ``popfilter`` act on the mode
  (:func:`arcsim_remesher_overrides`).

The fixed mesh of ``mode=nonadaptive`` is the input mesh remeshed once, at build time, to
uniform edges of ``fixed_edge`` metres (by the project's remesher with a constant sizing), since
ARCSim's input meshes are coarse drafts that its first remesh refines. The adaptive modes start
from the input mesh and refine it at frame 0, as ARCSim does.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components

from cloth.collision.contact import resolve_obstacle_contacts
from cloth.collision.meshobstacle import TriangleMeshObstacle
from cloth.collision.obstacles import ObstacleSet, Static
from cloth.core.measured import MeasuredMaterial, load_arcsim_material
from cloth.core.mesh import Mesh
from cloth.core.scene import Handle, Scene, SceneError, Wind
from cloth.io.arcsim import MAGIC_DEFAULTS, ArcsimConfig, ArcsimConfigError, load_arcsim_config
from cloth.remeshing.remesh import RemeshParams, remesh

# The effects an ARCSim scene can call for (cloth.core.scene.KNOWN_EFFECTS names).
ARCSIM_EFFECTS = ("membrane", "bending", "gravity", "wind", "damping", "obstacles", "self_collision",
                  "strain_limiting")
# At most this fraction of the contact thickness of obstacle motion per step: a frame takes more
# steps than the conf's frame_steps when an obstacle is fast (cloth.simulation, obstacle_steps).
# sphere.json's ball crosses the hanging sheet at 2 m/s, 1 cm per step at its 8 steps a frame,
# twice the 5 mm thickness: the contacts then pushed nodes 3-5 cm per step, the implicit step's
# velocity changes grew 1.25x a frame and the ball punched through the sheet at t = 2.3 s (elastic
# energy 1e4 J); at 32 steps a frame (2.5 mm per step) the energy peaks at 0.7 J and the sheet
# slides off the ball. ARCSim's own collision response (repulsion, then iterated CCD) is different.
OBSTACLE_STEP = 0.5
# A strain limit's lower bound when the conf gives none (ARCSim's -inf): a principal stretch
# this small is never reached, so it limits nothing.
NO_LOWER_STRETCH = 1e-9
# Magic numbers that ask for something this tool does not do, with the value that asks for nothing.
MAGIC_REFUSED = {"rib_stiffening": 1.0, "preserve_creases": False, "fixed_high_res_mesh": False}
# Magic numbers read for nothing here, with why (said in the scene's notes).
MAGIC_NOTED = {
    "collision_stiffness": "contacts are exact constraints here (no repulsion penalty stiffness)",
    "handle_stiffness": "pinned handles are exact constraints here (it is the fading spring's stiffness only)",
    "edge_flip_threshold": "the mode's remesh.flip_threshold applies",
    "combine_tensors": "the mode's sizing.combine applies",
}


def _load(conf, root) -> ArcsimConfig:
    if conf is None:
        raise SceneError("scene 'arcsim': scene.params.conf is required: the path of an ARCSim .json config")
    try:
        return load_arcsim_config(conf, root)
    except ArcsimConfigError as exc:
        raise SceneError(f"scene 'arcsim': {exc}") from None


def arcsim_end_frames(conf, root=None) -> int | None:
    """Frames the conf asks for: ``end_frame``, else ceil(end time / frame_time); None if neither."""
    cfg = _load(conf, root)
    if cfg.end_frame is not None:
        return int(cfg.end_frame)
    if math.isfinite(cfg.end_time):
        return max(int(math.ceil(cfg.end_time / cfg.frame_time - 1e-9)), 1)
    return None


def arcsim_remesher_overrides(conf, root=None, size_factor: float = 1.0) -> dict:
    """What the conf asks of the remeshing modes: its cloth's ``remeshing`` as sizing overrides
    (its smallest size x `size_factor`, so that a small-scale run stays small; the largest as
    given, which bounds how coarse a garment may get around a body), and whether it disables
    remeshing or the pop filter: {'sizing': {...}, 'remeshing': bool, 'pop_filter': bool}."""
    cfg = _load(conf, root)
    r = cfg.cloths[0].remeshing
    sizing = {}
    for key in ("refine_angle", "refine_compression", "refine_velocity", "aspect_min"):
        value = getattr(r, key)
        if math.isfinite(value):
            sizing[key] = float(value)
    if math.isfinite(r.size_min):
        sizing["size_min"] = float(r.size_min) * size_factor
    if math.isfinite(r.size_max):
        sizing["size_max"] = max(float(r.size_max), sizing.get("size_min", 0.0))
    off = cfg.disabled_modules
    return {"sizing": sizing, "remeshing": "remeshing" not in off, "pop_filter": "popfilter" not in off}


def _material(cfg: ArcsimConfig) -> MeasuredMaterial:
    entries = {c.materials[0] for c in cfg.cloths}
    if len(entries) > 1:
        raise SceneError(f"scene 'arcsim': {cfg.conf_path}: cloths: the cloths have different materials; "
                         "this tool simulates one material per scene")
    m = cfg.cloths[0].materials[0]
    # ARCSim's -inf / inf: no limit on that side (a stretch of NO_LOWER_STRETCH never happens)
    limits = ((m.strain_min if math.isfinite(m.strain_min) else NO_LOWER_STRETCH, m.strain_max)
              if m.strain_limited else None)
    return load_arcsim_material(m.data, thicken=m.thicken, density_mult=m.density_mult,
                                stretching_mult=m.stretching_mult, bending_mult=m.bending_mult,
                                damping=m.damping, strain_limits=limits, name=m.data.stem)


def _cloth_mesh(cfg: ArcsimConfig) -> tuple[Mesh, list[np.ndarray]]:
    """The cloths as one Mesh (material charts mirrored where the OBJ's are clockwise) and each
    cloth's node offset in it."""
    xs, vs, us, vns, fvs, offsets = [], [], [], [], [], []
    n_nodes = n_verts = 0
    for i, c in enumerate(cfg.cloths):
        u = np.array(c.vert_u, dtype=np.float64)
        fv = np.asarray(c.face_verts, dtype=np.int64)
        corners = u[fv]
        det = ((corners[:, 1, 0] - corners[:, 0, 0]) * (corners[:, 2, 1] - corners[:, 0, 1])
               - (corners[:, 1, 1] - corners[:, 0, 1]) * (corners[:, 2, 0] - corners[:, 0, 0]))
        if np.any(det < 0):
            _mirror_clockwise_charts(u, fv, det, f"{cfg.conf_path}: cloths[{i}].mesh ({c.mesh})")
        offsets.append(n_nodes)
        xs.append(c.node_x)
        vs.append(c.node_v)
        us.append(u)
        vns.append(np.asarray(c.vert_node, dtype=np.int64) + n_nodes)
        fvs.append(fv + n_verts)
        n_nodes += c.n_nodes
        n_verts += u.shape[0]
    mesh = Mesh(node_x=np.concatenate(xs), node_v=np.concatenate(vs), node_pinned=np.zeros(n_nodes, bool),
                vert_u=np.concatenate(us), vert_node=np.concatenate(vns).astype(np.int32),
                face_verts=np.concatenate(fvs).astype(np.int32))
    return mesh, offsets


def _mirror_clockwise_charts(u: np.ndarray, face_verts: np.ndarray, det: np.ndarray, where: str) -> None:
    """Mirror (u -> -u along the first axis, an isometry of the chart) every material chart whose
    faces are all clockwise, so that faces are counter-clockwise in material space as the project's
    mesh requires; a chart with both windings stops the run (edits `u`)."""
    F = face_verts.shape[0]
    rows = np.repeat(np.arange(F), 3)
    graph = coo_matrix((np.ones(3 * F), (rows, face_verts.reshape(-1))), shape=(F, u.shape[0])).tocsr()
    _, chart = connected_components(graph @ graph.T, directed=False)
    for c in np.unique(chart):
        faces = chart == c
        if np.all(det[faces] < 0):
            u[np.unique(face_verts[faces]), 0] *= -1.0
        elif np.any(det[faces] < 0):
            raise SceneError(f"scene 'arcsim': {where}: a material chart (texture island) has faces of "
                             "both windings in its vt coordinates")


def _rigid_motion(cfg: ArcsimConfig, index: int | None, key: str):
    if index is None:
        return Static()
    motion = cfg.motions[index]
    if motion.scale is None or abs(motion.scale - 1.0) > 1e-12:
        raise SceneError(f"scene 'arcsim': {cfg.conf_path}: {key}: a handle's motion may not scale "
                         f"(motion {index} has scale {motion.scale})")
    return motion


def _handles(cfg: ArcsimConfig, offsets: list[int]) -> list[Handle]:
    out = []
    for i, h in enumerate(cfg.handles):
        key = f"handles[{i}]"
        motion = _rigid_motion(cfg, h.motion, f"{key}.motion")
        for node in np.asarray(h.nodes, dtype=np.int64) + offsets[h.cloth]:
            handle = Handle(np.array([node]), motion, end_time=h.end_time, start_time=h.start_time,
                            fade_time=h.fade_time, stiffness=float(cfg.magic["handle_stiffness"]))
            handle.check(f"scene 'arcsim': {cfg.conf_path}: {key}")
            out.append(handle)
    return out


class RigidParts:
    """Vertex positions (V, 3) at time t of obstacle parts, each its rest vertices moved by its
    ARCSim motion (scale included) or at rest: a picklable callable for TriangleMeshObstacle."""

    def __init__(self, parts: list, n_vertices: int):
        self.parts = parts  # [(slice of the vertices, rest vertices (k, 3) m, motion or None)]
        self.n_vertices = n_vertices

    def __call__(self, t: float) -> np.ndarray:
        x = np.empty((self.n_vertices, 3))
        for sl, rest, motion in self.parts:
            x[sl] = rest if motion is None else motion.transform_at(t).apply(rest)
        return x


def _obstacle(cfg: ArcsimConfig) -> TriangleMeshObstacle | None:
    if not cfg.obstacles:
        return None
    parts, faces, offset = [], [], 0
    for i, ob in enumerate(cfg.obstacles):
        if ob.start_time > 0 or math.isfinite(ob.end_time):
            raise SceneError(f"scene 'arcsim': {cfg.conf_path}: obstacles[{i}]: obstacles with a start_time or "
                             "an end_time are not supported")
        motion = None if ob.motion is None else cfg.motions[ob.motion]
        parts.append((slice(offset, offset + ob.node_x.shape[0]), np.asarray(ob.node_x, dtype=np.float64), motion))
        faces.append(np.asarray(ob.face_nodes, dtype=np.int64) + offset)
        offset += ob.node_x.shape[0]
    moving = any(m is not None for _, _, m in parts)
    positions = RigidParts(parts, offset)
    name = Path(cfg.obstacle_pattern).stem if cfg.obstacle_pattern else cfg.obstacles[0].mesh.stem
    vertices = positions if moving else positions(0.0)
    return TriangleMeshObstacle(vertices, np.concatenate(faces), name=name)


def _effects(cfg: ArcsimConfig, material: MeasuredMaterial, obstacle, requested) -> frozenset:
    off = cfg.disabled_modules
    if "physics" in off:
        raise SceneError(f"scene 'arcsim': {cfg.conf_path}: disable: 'physics' cannot be disabled here")
    w = cfg.wind
    wants = {
        "membrane": True, "bending": True,
        "gravity": bool(np.any(cfg.gravity != 0)),
        "wind": w.density > 0 or w.drag > 0,  # ARCSim's air acts on moving cloth even without wind
        "damping": material.damping_stiffness > 0,
        "obstacles": obstacle is not None,
        "self_collision": not ({"collision", "proximity"} & off),
        "strain_limiting": material.strain_limits is not None and "strainlimiting" not in off,
    }
    called = {e for e, on in wants.items() if on}
    if not requested:
        return frozenset(called)
    extra = set(requested) - called
    if extra:
        raise SceneError(f"scene 'arcsim': effects {sorted(extra)} are not called for by {cfg.conf_path} "
                         f"(it calls for {sorted(called)})")
    return frozenset(requested) | {"membrane"}


def _notes(cfg: ArcsimConfig) -> tuple:
    notes = []
    for key, value in cfg.magic.items():
        if key in MAGIC_REFUSED and value != MAGIC_REFUSED[key]:
            raise SceneError(f"scene 'arcsim': {cfg.conf_path}: magic.{key}: {value!r} is not supported "
                             f"(only {MAGIC_REFUSED[key]!r})")
        if key in MAGIC_NOTED and value != MAGIC_DEFAULTS.get(key):
            notes.append(f"ARCSim magic.{key} = {value!r} not used: {MAGIC_NOTED[key]}")
    return tuple(notes)


def uniform_mesh(mesh: Mesh, handles: list[Handle], edge: float, density: float) -> Mesh:
    """`mesh` remeshed to uniform edges of about `edge` m (the project's remesher with the constant
    sizing I / edge^2), handle nodes kept (each handle's node list updated in place)."""
    handle_id = np.full(mesh.n_nodes, -1, dtype=np.int64)
    for i, h in enumerate(handles):
        handle_id[h.nodes] = i
    vert_M = np.broadcast_to(np.eye(2) / edge**2, (mesh.n_verts, 2, 2)).copy()
    data = np.hstack([mesh.node_x, mesh.node_v])
    mesh.update_rest_data(density)
    for _ in range(8):  # each pass at most doubles the faces along an edge; 8 passes: 256x coarser input
        result = remesh(mesh, vert_M, data, handle_id, RemeshParams())
        if not result.changed:
            break
        mesh, data, handle_id = result.mesh, result.node_data, result.node_handle
        mesh.update_rest_data(density)
        vert_M = np.broadcast_to(np.eye(2) / edge**2, (mesh.n_verts, 2, 2)).copy()
    for i, h in enumerate(handles):
        h.nodes = np.flatnonzero(handle_id == i)
    mesh.node_pinned[:] = False
    return mesh


def _push_out(mesh: Mesh, obstacle, thickness: float) -> None:
    """Move free nodes nearer than `thickness` to the obstacle (or inside it) out to it, at t = 0,
    with the frame loop's own contact projection (edits mesh.node_x; velocities stay at rest)."""
    obstacles = ObstacleSet([obstacle])
    obstacles.set_time(0.0)
    scratch_v = mesh.node_v.copy()  # the projection edits velocities; the initial state keeps its own
    resolve_obstacle_contacts(mesh.node_x, scratch_v, mesh.node_pinned, obstacles, thickness, 0.0, 1.0)


# m: standard deviation (each axis) of the seeded noise on the free cloth nodes of an ARCSim scene
# run with seed > 0 (the characters' CHARACTER_JITTER): a fiftieth of ARCSim's 5 mm thickness, so
# that seeds give distinct trajectories of the same scene.
ARCSIM_JITTER = 1e-4


def arcsim_scene(material=None, *, conf: str | None = None, root: str | None = None, mode_mesh: str = "input",
                 fixed_edge: float | None = None, size_factor: float = 1.0, effects=(), seed: int = 0,
                 jitter: float = ARCSIM_JITTER) -> Scene:
    """The ARCSim scene of `conf` (module docstring). `material` (the run's material group) is
    unused: the conf names its own. `mode_mesh`: "input" (the OBJ as it is, for the remeshing
    modes) or "uniform" (remeshed to edges of `fixed_edge` m, default the conf's smallest size x
    `size_factor`: the fixed mesh of mode=nonadaptive). `seed` 0 starts from the conf's own mesh
    (what ARCSim's output is compared with); a seed s > 0 adds seeded noise of `jitter` m (standard
    deviation, each axis) to the cloth nodes no handle holds, so that seeds give distinct
    trajectories."""
    if not (isinstance(seed, int) and seed >= 0):
        raise SceneError(f"scene 'arcsim': seed must be an integer >= 0, got {seed!r}")
    if not (isinstance(jitter, (int, float)) and math.isfinite(jitter) and jitter >= 0):
        raise SceneError(f"scene 'arcsim': jitter must be >= 0 m, got {jitter!r}")
    if conf is None:
        raise SceneError("scene 'arcsim': scene.params.conf is required: the path of an ARCSim .json config")
    if mode_mesh not in ("input", "uniform"):
        raise SceneError(f"scene 'arcsim': mode_mesh must be 'input' or 'uniform', got {mode_mesh!r}")
    if not size_factor > 0:
        raise SceneError(f"scene 'arcsim': size_factor must be > 0, got {size_factor!r}")
    cfg = _load(conf, root)
    measured = _material(cfg)
    mesh, offsets = _cloth_mesh(cfg)
    handles = _handles(cfg, offsets)
    obstacle = _obstacle(cfg)
    scene_effects = _effects(cfg, measured, obstacle, tuple(effects))
    if "strain_limiting" not in scene_effects and measured.strain_limits is not None:
        measured = replace(measured, strain_limits=None)  # disabled by the conf or left out of the list
    notes = _notes(cfg)
    if mode_mesh == "uniform":
        if fixed_edge is None:
            size_min = cfg.cloths[0].remeshing.size_min
            if not math.isfinite(size_min):
                raise SceneError(f"scene 'arcsim': {cfg.conf_path} gives no remeshing size: "
                                 "set scene.params.fixed_edge")
            fixed_edge = size_min * size_factor
        if not fixed_edge > 0:
            raise SceneError(f"scene 'arcsim': fixed_edge must be > 0 m, got {fixed_edge!r}")
        mesh = uniform_mesh(mesh, handles, float(fixed_edge), measured.density)
        if obstacle is not None:  # the new nodes on chords of the coarse input around a body lie inside it
            _push_out(mesh, obstacle, float(cfg.magic["repulsion_thickness"]))
    if seed > 0 and jitter > 0:
        held = np.zeros(mesh.n_nodes, dtype=bool)
        for h in handles:
            held[h.nodes] = True
        noise = jitter * np.random.default_rng(seed).standard_normal(mesh.node_x.shape)
        noise[held | mesh.node_pinned] = 0.0
        mesh.node_x += noise
    w = cfg.wind
    wind = (Wind(velocity=tuple(float(v) for v in w.velocity), drag=0.0, density=float(w.density),
                 drag_tangential=float(w.drag)) if "wind" in scene_effects else None)
    return Scene(name=f"arcsim_{Path(conf).stem}", mesh=mesh, material=measured, effects=scene_effects,
                 frame_time=cfg.frame_time, steps_per_frame=cfg.frame_steps,
                 gravity=tuple(float(g) for g in cfg.gravity), wind=wind,
                 obstacles=[obstacle] if obstacle is not None and "obstacles" in scene_effects else [],
                 handles=handles, thickness=float(cfg.magic["repulsion_thickness"]),
                 self_thickness=float(cfg.magic["projection_thickness"]),
                 friction=float(cfg.obs_friction), self_friction=float(cfg.friction), notes=notes,
                 obstacle_step=OBSTACLE_STEP if obstacle is not None else None)
