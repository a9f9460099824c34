"""The remesh stage of the frame loop (mode=adaptive; mode=viewdep changes only `face_sizing`).

Once every `every` frames, before the frame's steps:

    sizing field per face  ->  area-weighted transfer to verts  ->  remesh (cloth.remeshing.remesh)
    [->  crossing guard: redo the remesh with new crossings' nodes frozen; failing that, splits
         alone or no remesh this frame]
    ->  rebuild masses, rest data, sparsity (Simulation.rebuild)
    ->  push nodes out of obstacles  ->  pop filter  ->  push nodes out of obstacles
    [->  the push-outs' and pop filter's motion made free of collisions with the cloth itself
         and with triangle-mesh obstacles (standing still)]

The bracketed stages run in scenes that declare `self_collision`. Without them, a dense pile
or a layered garment is remeshed into crossings: a flip or collapse near another layer passes
the new faces through it (the guard), and the push-out and pop filter move nodes through a
layer within the thickness (the self-collision response treats their displacement as a step's
motion, `collision_free_motion`). What still crosses is untangled by the frame loop.

A split puts its new node at the midpoint of the edge's nodes; where the edge spans a curved
obstacle (a coarse face over a sphere) that midpoint lies inside it, centimetres deep. Those
nodes are moved out to the contact thickness (positions only, velocities unchanged) before the
pop filter, which then relaxes the strain this causes around them, and again after it.

The first remesh (frame 0) refines or coarsens the input mesh to its sizing and runs no pop
filter: the cloth has no history to keep.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np

from cloth.collision.bvh import cross_overlaps
from cloth.collision.meshobstacle import mesh_obstacle_triangles
from cloth.collision.selfcollision import resolve_collisions_with_obstacles, resolve_self_collisions
from cloth.collision.untangle import find_intersections, obstacle_crossings
from cloth.remeshing.popfilter import PopFilterParams, internal_forces, pop_filter
from cloth.remeshing.remesh import RemeshParams, RemeshResult, remesh
from cloth.remeshing.sizing import SizingParams, face_to_vert_sizing, physics_face_sizing, sizing_at_bounds

INTERNAL_TERMS = ("membrane", "bending")
# Crossing guard (scenes with self_collision): when a remesh made the cloth cross itself (more
# crossing face pairs than it had), it is redone from the same input with the nodes around the
# new crossings frozen (no flip or collapse there), at most this many times; what is left goes
# to the untangling.
CROSSING_GUARD_ROUNDS = 3
# Padding of a crossing pair's box, in units of its longest edge, tried in turn until the box
# holds an input node not yet frozen (a box around new split nodes may hold none).
CROSSING_GUARD_PADS = (0.0, 0.5, 1.0, 2.0)
# Pop filter and obstacle push-out, alternated at most this many times (until the push-out has
# nothing to move). Refining coarse cloth draped on a curved obstacle puts each new midpoint
# inside it by the chord's sagitta (4-8 cm for 0.4 m edges on the 0.25 m sphere); pushed out
# alone, it stretches its small new faces (12-15 J of membrane energy in a 0.12 kg sheet), the
# pop filter relaxes that but, blind to the obstacle, pulls nodes back in, and the second
# push-out restored the stretch: viewdep sheet_on_sphere runs reached 1.6 J of kinetic energy
# in one frame. With three rounds the same run stays below 0.05 J after the first contact.
POP_PUSH_ROUNDS = 3
# The rounds stop early when the push-out strained no edge by more than this: every pushed node
# moved less than this fraction of its shortest edge. After the first round the pushes on a sheet
# resting on the sphere are 0.1-0.5 mm deep, and the second and third rounds changed the filtered
# energy by less than 3 % while costing 40 % of the remesh. (A bound on the depth alone, a
# quarter of the thickness, let the view-dependent sheet_on_sphere diverge at frame 15: its
# 1.25 mm pushes were a large strain on its finest edges.)
POP_PUSH_STRAIN = 0.01
# After the first round the pop filter relaxes only the faces within this many rings of the
# nodes the push-out moved (the others were relaxed already and the push-out left their nodes
# where they were); -1: every changed face again. On the refinement case of
# tests/test_adaptive.py (seeds 0-5) the energy after the filter differs from the full rounds'
# by less than 0.5 %, and at 12k faces a remesh costs 1.1 s instead of 2.3 s.
POP_PUSH_RINGS = 2
# A node a split made inside an obstacle passes through it until it is out (mark_passing) when
# all three hold: it is deeper than PASSING_DEPTH contact thicknesses (within one the push-out
# moves a node no more than a step's contact does); its edge's two nodes lie on opposite sides of
# the obstacle (the mean of their obstacle normals, carried by the split, has a component below
# PASSING_NORMAL along the normal at the new node); and the obstacle is thin there: PASSING_PROBE
# node depths beyond the node, away from its nearest surface, the obstacle is less than
# PASSING_PROBE node depths deep, i.e. it is less than 2 PASSING_PROBE + 1 node depths thick along
# that line (a thick obstacle is 2 PASSING_PROBE + 1 depths deep there: a clear margin).
# Measured: the four nodes in a dancer's leg (ten dancers without the contact floor, dancer 5,
# frame 15) were 3.5-5.0 cm deep in 10-15 cm of leg (2.0-3.3 node depths beyond them: 0.0-4.5 cm
# deep) with components 0.03-0.16; refining 0.4 m faces on the 0.25 m sphere (seeds 0-5,
# tests/test_adaptive.py) made nodes up to 7.4 cm deep, components down to -0.2 (splits of splits
# average normals over long arcs), but 0.5 m of sphere along the line: 6.8 node depths or more.
PASSING_DEPTH = 1.0
PASSING_NORMAL = 0.5
PASSING_PROBE = 2.0


def restore_momentum(mesh, momentum: np.ndarray) -> None:
    """Give the free nodes the uniform velocity change that restores the linear momentum.

    Splits conserve momentum exactly (a new node takes its edge's mean velocity and the lumped
    masses redistribute symmetrically); a collapse drops its node's momentum. Of all velocity
    corrections that restore sum(m v), a uniform one has the least kinetic energy.
    """
    free = ~mesh.node_pinned
    m_free = float(mesh.node_m[free].sum())
    if m_free > 0:
        mesh.node_v[free] += (momentum - mesh.node_m @ mesh.node_v) / m_free


def faces_near(face_nodes: np.ndarray, nodes: np.ndarray, rings: int) -> np.ndarray:
    """(F,) bool: the faces with a node within `rings` face rings of the marked `nodes` (n,) bool
    (rings = 0: the faces touching a marked node)."""
    near = nodes.copy()
    for _ in range(rings):
        near[face_nodes[near[face_nodes].any(axis=1)].reshape(-1)] = True
    return near[face_nodes].any(axis=1)


def push_strain(mesh, displacement: np.ndarray, moved: np.ndarray) -> float:
    """The largest |displacement| / (shortest rest edge at the node) over the `moved` nodes (n,) bool:
    a bound on the strain a push-out put on the edges around them."""
    if not np.any(moved):
        return 0.0
    shortest = np.full(mesh.n_nodes, np.inf)
    for k in range(2):
        np.minimum.at(shortest, mesh.edge_nodes[:, k], mesh.edge_rest_length)
    return float(np.max(np.linalg.norm(displacement[moved], axis=1) / shortest[moved]))


def push_out_of_obstacles(sim) -> dict:
    """Move free nodes inside an obstacle out to the contact thickness; velocities are kept.

    Returns the contact projection's statistics (nodes moved, deepest penetration).
    """
    if sim.contact is None:
        return {"contacts": 0, "max_depth_m": 0.0}
    mesh = sim.mesh
    sim.obstacle_set.set_time(sim.time)
    scratch_v = mesh.node_v.copy()  # the projection edits velocities; a remesh must not
    return sim.contact(mesh.node_x, scratch_v, sim.contact_exempt(), sim.obstacle_set, sim.scene.thickness, 0.0,
                       sim.scene.dt)


def obstacle_normals(sim) -> np.ndarray:
    """(n_nodes, 3): the nearest obstacle's outward normal at every node (zeros without
    obstacle contact). A remesh carries them as node data, so that a split node holds the mean of
    its edge's two nodes' normals (:func:`mark_passing`)."""
    if sim.contact is None:
        return np.zeros((sim.mesh.n_nodes, 3))
    sim.obstacle_set.set_time(sim.time)
    return sim.obstacle_set.query(sim.mesh.node_x)[1]


def mark_passing(sim, node_origin: np.ndarray, old_passing: np.ndarray, carried_normal: np.ndarray) -> int:
    """Set sim.node_passing for the remeshed mesh; return how many nodes pass.

    A kept node keeps its flag. A node the remesh made (a split) lies on the old surface. Deep
    inside an obstacle it is either under a chord of a curved obstacle (the nearest surface is the
    right one, POP_PUSH_ROUNDS) or on an edge through a thin part of it (a coarse face through a
    leg: contact holds nodes, not faces). Pushing the second kind to the nearest surface chooses a
    side, often the far one, and hooks the cloth around the limb (the ten dancers without the
    contact floor, dancer 5: four split nodes 3.5-5 cm inside a leg, pushed out, stretched faces 9
    times in five frames and the run diverged). They are told apart by `carried_normal` (the mean
    of the edge's nodes' obstacle normals, :func:`obstacle_normals`: the two sides) and by the
    obstacle's thickness along the node's normal (PASSING_PROBE). Such a node passes: obstacle
    contact leaves it alone until it is out (Simulation.release_passing), as it left the face it
    was made on.
    """
    flags = np.zeros(sim.mesh.n_nodes, dtype=bool)
    kept = node_origin >= 0
    if len(old_passing):
        flags[kept] = old_passing[node_origin[kept]]
    made = np.flatnonzero(~kept & ~sim.mesh.node_pinned)
    if sim.contact is not None and made.size:
        sim.obstacle_set.set_time(sim.time)
        x = sim.mesh.node_x[made]
        phi, normal, _ = sim.obstacle_set.query(x)
        across = np.einsum("ij,ij->i", carried_normal[made], normal) < PASSING_NORMAL
        c = np.flatnonzero((phi < -PASSING_DEPTH * sim.scene.thickness) & across)
        if c.size:  # the normal points out through the nearest surface, -phi away
            beyond = sim.obstacle_set.query(x[c] + PASSING_PROBE * phi[c, None] * normal[c])[0]
            flags[made[c[-beyond < PASSING_PROBE * -phi[c]]]] = True
    sim.node_passing = flags
    return int(flags.sum())


def collision_free_motion(sim, x_from: np.ndarray) -> int:
    """Make the motion of the nodes from `x_from` to where they are now free of collisions.

    The obstacle push-out and the pop filter move nodes after a remesh without looking at the
    other layers of cloth; a layer within the thickness of another is then pushed through it.
    Their displacement is treated like a step's motion: the self-collision response (proximity,
    CCD, impact zones) corrects it, so a remesh that made no crossing leaves none. With
    triangle-mesh obstacles they are in the same pass, standing still: the response's own moves
    (a proximity push between two layers) could otherwise carry the inner layer into the body
    (ARCSim's dress-blue, seed 1, frame 337: a pass that found no CCD collision left 12 cloth-body
    crossings). Nodes inside an obstacle at `x_from` (a split's midpoint, a passing node) are left
    out of the cloth-obstacle pairs, as in a step: the push-out is what moves them out. Positions
    only: velocities are the remesh's. Returns the CCD collisions found.
    """
    mesh = sim.mesh
    obstacles = getattr(sim, "mesh_obstacles", None)
    if not obstacles:
        s = resolve_self_collisions(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x_from, mesh.node_x,
                                    mesh.node_m, mesh.node_pinned, sim.self_collision)
        return int(s["self_ccd_hits"])
    sim.obstacle_set.set_time(sim.time)
    still = [(ob.positions, ob.positions, *ob.collision_topology()) for ob in obstacles]
    skip = sim.node_passing.copy()
    free = ~mesh.node_pinned
    skip[free] |= sim.obstacle_set.query(x_from[free])[0] < 0.0
    s = resolve_collisions_with_obstacles(mesh.face_nodes, mesh.face_edges, mesh.edge_nodes, x_from, mesh.node_x,
                                          mesh.node_m, mesh.node_pinned, sim.mesh_collision, still,
                                          self_pairs=sim.self_collision is not None, skip=skip,
                                          trees=getattr(sim, "_collision_trees", None))
    return int(s["self_ccd_hits"] + s["obstacle_ccd_hits"])


def keep_obstacles_uncrossed(sim, x_from: np.ndarray) -> int:
    """Put back, to `x_from`, the nodes whose move since made a face of theirs cross a triangle-mesh
    obstacle; returns how many were put back.

    The obstacle push-out moves a node along its nearest surface's normal, blind to its faces: in a
    hollow (an armpit, a skirt between the legs) a node pushed off the arm carries its face into
    the torso (ARCSim's dress-blue, seed 2, frame 336: six nodes 1.6 mm from the body pushed out
    3 mm made 15 cloth-body crossings, and the untangling that followed left one of the cloth with
    itself). A node within the thickness but outside needs no push (the next step's contact holds
    it), and a node the remesh made inside the body crosses already; so a move that adds a crossing
    is undone, repeated while undoing one adds another (at worst back to `x_from`).
    """
    if not getattr(sim, "mesh_obstacles", None):
        return 0
    mesh = sim.mesh
    moved = np.any(mesh.node_x != x_from, axis=1)
    if not moved.any():
        return 0
    sim.obstacle_set.set_time(sim.time)
    obstacles = mesh_obstacle_triangles(sim.mesh_obstacles)
    undone = 0
    while moved.any():
        faces = np.flatnonzero(moved[mesh.face_nodes].any(axis=1))
        now = obstacle_crossings(mesh.face_nodes, mesh.node_x, obstacles, faces)
        if len(now) == 0:
            break
        before = obstacle_crossings(mesh.face_nodes, x_from, obstacles, np.unique(now[:, 0]))
        new = now[~_rows_in(now, before)]
        nodes = np.unique(mesh.face_nodes[new[:, 0]])
        nodes = nodes[moved[nodes]]
        if nodes.size == 0:
            break
        mesh.node_x[nodes] = x_from[nodes]
        moved[nodes] = False
        undone += int(nodes.size)
    return undone


def _rows_in(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(len(a),) bool: rows of the (K, 2) int array a that are rows of b."""
    if len(b) == 0:
        return np.zeros(len(a), dtype=bool)
    return (a[:, None, :] == b[None, :, :]).all(axis=2).any(axis=1)


def changed_faces(old, new, node_origin: np.ndarray) -> np.ndarray:
    """(new.n_faces,) bool: faces of `new` that were not faces of `old` (by their nodes).

    `node_origin` gives, per node of `new`, its node in `old` or -1 for a node the remesh made.
    """
    fo = node_origin[new.face_nodes]
    changed = (fo < 0).any(axis=1)
    n = np.int64(old.n_nodes)
    def key(t):
        t = np.sort(t.astype(np.int64), axis=1)
        return (t[:, 0] * n + t[:, 1]) * n + t[:, 2]
    changed |= ~np.isin(key(np.maximum(fo, 0)), key(old.face_nodes))
    return changed


@dataclass
class AdaptiveRemesher:
    sizing: SizingParams = field(default_factory=SizingParams)
    params: RemeshParams = field(default_factory=RemeshParams)
    pop: PopFilterParams | None = field(default_factory=PopFilterParams)
    every: int = 1  # remesh once every this many frames

    def __post_init__(self):
        if int(self.every) < 1:
            raise ValueError(f"remesh every must be >= 1 frame, got {self.every}")

    # the one method a sizing variant overrides (mode=viewdep)
    def steps_for_frame(self, sim) -> int:
        """Implicit steps of the coming frame: the scene's (mode=viewdep takes fewer for a
        character wholly out of view, cloth.view.viewdep)."""
        return sim.scene.steps_per_frame

    def face_sizing(self, sim) -> np.ndarray:
        obstacles = sim.obstacle_set if sim.contact is not None else None
        return physics_face_sizing(sim.mesh, self.sizing, obstacles)

    def _avoid_crossings(self, mesh, vert_M, data, handle_id, result, stats):
        """Redo a remesh that made the cloth cross itself, with the crossings' surroundings frozen.

        Splits keep the surface (a new node on its edge), but a flip replaces two faces by the
        other diagonal's and a collapse moves a node onto its neighbour; where another layer lies
        within the change, the new faces cross it, and CCD, which assumes a crossing-free start,
        cannot see that. The input nodes within each new crossing's reach (its two faces' box,
        padded if need be, CROSSING_GUARD_PADS) are frozen, and the remesh runs again; the frozen set grows
        until the remesh adds no crossing or CROSSING_GUARD_ROUNDS is reached.

        The rounds need not improve one on another (a redo takes other paths around what it may not
        touch; karate, view-dependent, seed 3: 79, 4, 1, then 7 crossings). When no round adds no
        crossing, the remesh falls back (`remesh_guard_fallback`): 1, to splits alone (every node
        frozen: a split only subdivides faces, so it makes no crossing), unless that makes a sliver;
        2, to no remesh this frame (the mesh as it was). Either way the remesh adds no crossing.
        """
        n_before, current, pairs = None, result, None
        frozen = np.zeros(mesh.n_nodes, dtype=bool)
        # a face of aspect 12 sqrt(3) A / P^2 >= aspect_min has quality 4 sqrt(3) A / sum(l^2) >=
        # aspect_min / 3 (sum(l^2) <= P^2): the bound a redo may not break unless the unguarded remesh did
        quality_floor = min(self.params.aspect_min / 3, float(result.mesh.face_quality().min()))
        for r in range(CROSSING_GUARD_ROUNDS + 1):
            out = current.mesh
            pairs = find_intersections(out.face_nodes, out.node_x)[0]
            if n_before is None:
                if len(pairs) == 0:
                    return current
                n_before = len(find_intersections(mesh.face_nodes, mesh.node_x)[0])
            if len(pairs) <= n_before:
                return current
            if r == CROSSING_GUARD_ROUNDS:
                break
            corners = out.node_x[out.face_nodes[pairs].reshape(len(pairs), 6)]  # (P, 6, 3)
            edges = corners[:, [1, 2, 0, 4, 5, 3]] - corners
            longest = np.sqrt(np.einsum("pij,pij->pi", edges, edges).max(axis=1))[:, None]
            for pad in CROSSING_GUARD_PADS:  # the pairs' boxes, padded only if they hold no new input node
                near = cross_overlaps(mesh.node_x, mesh.node_x, corners.min(axis=1) - pad * longest,
                                      corners.max(axis=1) + pad * longest)[:, 0]
                if not frozen[near].all():
                    break
            if frozen[near].all():
                break  # nothing more to freeze: the crossings were there before
            frozen[near] = True
            redo = remesh(mesh, vert_M, data, handle_id, self.params, frozen=frozen)
            if redo.mesh.face_quality().min() < quality_floor:
                # frozen nodes block the flips that repair a split's thin faces (a split of a thin
                # face's short edge makes faces of a third of its quality): no sliver to the solver
                stats["remesh_guard_refused"] = stats.get("remesh_guard_refused", 0) + 1
                break
            current = redo
            stats.update(remesh_guard_rounds=r + 1, remesh_frozen_nodes=int(frozen.sum()))
        splits = remesh(mesh, vert_M, data, handle_id, self.params, frozen=np.ones(mesh.n_nodes, dtype=bool))
        if splits.mesh.face_quality().min() >= quality_floor and \
                len(find_intersections(splits.mesh.face_nodes, splits.mesh.node_x)[0]) <= n_before:
            stats["remesh_guard_fallback"] = 1
            return splits
        stats["remesh_guard_fallback"] = 2
        return RemeshResult(mesh=mesh, node_data=data, node_handle=handle_id, node_origin=np.arange(mesh.n_nodes),
                            vert_M=vert_M, splits=0, collapses=0, flips=0, changed=False)

    def remesh(self, sim, timings: dict, stats: dict) -> bool:
        """Remesh `sim` if this frame is due; True when the mesh changed."""
        if sim.frame % int(self.every) != 0:
            return False
        mesh = sim.mesh
        t0 = time.perf_counter()
        face_M = self.face_sizing(sim)
        vert_M = face_to_vert_sizing(mesh, face_M)
        t1 = time.perf_counter()
        timings["sizing"] += t1 - t0
        stats.update(sizing_at_bounds(mesh, face_M, self.sizing.size_min, self.sizing.size_max))
        t1 = time.perf_counter()  # the count above is the record's bookkeeping, not remeshing
        initial = sim.frame == 0
        internal = [t for t in sim.terms if t.name in INTERNAL_TERMS]
        use_pop = self.pop is not None and not initial and bool(internal) and self.pop.iterations > 0
        # per-node data a split averages: x, v, internal force per unit mass, handle anchor, obstacle normal
        handle_id = np.full(mesh.n_nodes, -1, dtype=np.int64)
        anchor = np.zeros((mesh.n_nodes, 3))
        for i, h in enumerate(sim.scene.handles):
            handle_id[h.nodes] = i
            anchor[h.nodes] = h.local
        static = mesh.node_pinned & (handle_id < 0)
        handle_id[static] = len(sim.scene.handles)  # pinned without a handle: a group of its own
        a_int = np.zeros((mesh.n_nodes, 3))
        if use_pop:  # internal forces of the old mesh, per unit mass, carried onto the new nodes
            a_int = internal_forces(mesh, internal, sim.pattern) / mesh.node_m[:, None]
        momentum = mesh.node_m @ mesh.node_v
        data = np.hstack([mesh.node_x, mesh.node_v, a_int, anchor, obstacle_normals(sim)])
        result = remesh(mesh, vert_M, data, handle_id, self.params)
        if sim.self_collision is not None and result.changed:
            result = self._avoid_crossings(mesh, vert_M, data, handle_id, result, stats)
        stats.update(remeshed=1, remesh_splits=result.splits, remesh_collapses=result.collapses,
                     remesh_flips=result.flips)
        if not result.changed:
            stats["remesh_nodes_passing"] = int(sim.node_passing.sum())
            timings["remesh"] += time.perf_counter() - t1
            return False
        new = result.mesh
        nd = result.node_data
        old_passing = sim.node_passing
        sim.scene.mesh = new
        for i, h in enumerate(sim.scene.handles):
            sel = np.flatnonzero(result.node_handle == i)
            h.nodes = sel
            h.local = np.ascontiguousarray(nd[sel, 9:12])
            new.node_pinned[sel] = h.pinned  # a waiting or fading handle's nodes are kept, not pinned
        sim.rebuild()
        restore_momentum(new, momentum)
        x_topo = new.node_x.copy()  # the remeshed surface: the old one, re-triangulated
        stats["remesh_nodes_passing"] = mark_passing(sim, result.node_origin, old_passing, nd[:, 12:15])
        pushed = push_out_of_obstacles(sim)
        stats.update(remesh_nodes_pushed_out=pushed["contacts"], remesh_max_depth_m=pushed["max_depth_m"])
        if use_pop:
            target = nd[:, 6:9] * new.node_m[:, None]
            changed = changed_faces(mesh, new, result.node_origin)
            rounds = []
            for _ in range(POP_PUSH_ROUNDS):
                rounds.append(pop_filter(new, internal, changed, target, self.pop, sim.solver))
                x_before = new.node_x.copy()
                if push_out_of_obstacles(sim)["contacts"] == 0:
                    break
                moved = np.any(new.node_x != x_before, axis=1)
                if push_strain(new, new.node_x - x_before, moved) < POP_PUSH_STRAIN:
                    break
                if POP_PUSH_RINGS >= 0:
                    changed = faces_near(new.face_nodes, moved, POP_PUSH_RINGS)
            stats.update(pop_energy_before_j=rounds[0]["energy_before_j"],
                         pop_energy_after_j=rounds[-1]["energy_after_j"],
                         pop_iterations=sum(r["iterations"] for r in rounds),
                         pop_reverted=sum(r["reverted"] for r in rounds))
        stats["remesh_obstacle_moves_undone"] = keep_obstacles_uncrossed(sim, x_topo)
        if sim.self_collision is not None:
            stats["remesh_ccd_hits"] = collision_free_motion(sim, x_topo)
        timings["remesh"] += time.perf_counter() - t1
        return True
