"""Cloth self-collision over one step: proximity repulsion, continuous collision detection and
rigid impact zones (Bridson, Fedkiw and Anderson 2002; Provot 1997), on node positions.

Given the positions x0 at the start of a step (assumed free of intersections) and the
positions x1 the integrator proposes at its end, `resolve_self_collisions` changes x1 so that

1. **proximity**: vertex-face and edge-edge pairs closer than the thickness at x1 are pushed
   apart to the thickness on the side they were on at x0 (mass-weighted, with the primitives'
   barycentric weights, so a pair that crossed during the step is pushed back; two cloth
   primitives only across the sheets, by `self_thickness` when given), with
   Coulomb friction on their relative tangential motion over the step;
2. **continuous collision detection**: every vertex-face and edge-edge pair that touches
   during the linear motion x0 -> x1 (roots of the coplanarity cubic, `cloth.collision.ccd`) is given a
   correction that leaves it on its starting side by a small separation at the end of the
   step; repeated in Gauss-Seidel passes until a pass finds nothing or the pass limit is hit;
3. **rigid impact zones**: if collisions remain, the nodes of each colliding pair are merged
   into zones (with the zones already found) and each zone moves rigidly with its own linear
   and angular momentum over the step. A rigid motion of a collision-free configuration has no
   internal collisions, and zones only grow, so this terminates: at worst with one zone that
   holds every colliding node. A zone with pinned cloth nodes (infinite mass) takes the rigid
   motion that best fits their displacement (`pinned_fit`); a zone with obstacle nodes is
   separated by inelastic projection instead (below). What is left after `max_zone_passes` is
   counted in the record (never aborts).

The caller turns the change of x1 into a change of velocity (dv = dx1 / h). Pairs that share
a node are never tested (adjacent elements touch by construction), nor pairs none of whose
nodes can move (every node pinned: no response can change them).

**Obstacles.** `resolve_collisions_with_obstacles` runs the same three stages between the cloth
and triangle-mesh obstacles (cloth.collision.meshobstacle) moving linearly over the step from their
start to their end positions: the obstacles' triangles are appended to the cloth's as fixed
faces whose nodes are pinned (infinite mass, inv_m = 0), so every correction moves only the
cloth, and face pairs are taken between the cloth and the obstacles (and within the cloth when
asked), never between two obstacle faces. An impact zone holding obstacle nodes is not moved
rigidly: the best rigid fit of a body that deforms within the step (fingers bending against a
hand) leaves collisions round after round (the dress on ARCSim's dancing body gave up after 48
rounds). Its free nodes go back to where the zones started and are moved the least, in the
mass-weighted norm, that separates every impact the zone has gathered (inelastic projection,
Harmon, Vouga, Tamstorf and Grinspun 2008, as ARCSim's zones: each impact's weights and normal
at its touch, `cloth.collision.impactzones.inelastic_projection`). What is left after the rounds
is counted (`obstacle_collisions_left`).

This module holds the parameters and the two drivers; the stages are in their own modules:

* cloth.collision.candidates, the broad phase: a bounding-volume hierarchy over face boxes
  (cloth.collision.bvh) gives the face pairs; each node and edge is then tested from one face
  only (its owner), so each vertex-face and edge-edge pair comes once;
* cloth.collision.response, stages 1 and 2: a slab test along the face normal or the edges'
  cross product rejects most pairs before the exact distance or the CCD cubic
  (cloth.collision.ccd.vf_separated, ee_separated);
* cloth.collision.impactzones, stage 3: the zones (union-find), their rigid motion, `pinned_fit`,
  and the inelastic projection of zones with obstacle nodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cloth.collision.candidates import (
    overlapping_face_pairs,
    owner_faces,
    primitive_pairs,
    swept_boxes,
)
from cloth.collision.impactzones import (
    PROJECTION_SWEEPS,
    PROJECTION_TOLERANCE,
    inelastic_projection,
    merge_zones,
    rigid_motion,
)
from cloth.collision.response import ccd_pass, proximity_repulsion
from cloth.core.records import OBSTACLE_RECORD, SELF_COLLISION_RECORD

# CCD counts a touch when two primitives come within this fraction of the thickness: the
# coplanarity roots are exact only up to round-off, and a zero-distance test would miss grazes.
CCD_ETA_FRACTION = 1e-3
# After a CCD correction the pair ends this fraction of the thickness apart on its starting
# side: enough that round-off does not put it back into contact, small enough that the
# correction does not start new collisions (the proximity stage of the next step restores the
# full thickness).
CCD_SEPARATION_FRACTION = 0.1
# The pass reuses its broad phase's face pairs while they still hold every query's, and a later CCD
# pass takes only those with a node the previous pass moved (see `pairs` in resolve_self_collisions);
# False finds every query's pairs afresh from all faces (the same result, slower: a test compares the two).
REUSE_BROAD_PHASE = True
# An impact-zone round after the first tests only the pairs with a node the previous round moved
# or hit (see the zone loop in resolve_self_collisions); False tests every pair in every round
# (the same hits in the same order, slower: a test compares the two). On a karate frame whose
# zones grow to 250 nodes over 11-15 rounds per step, the collision pass is 1.17x faster.
ZONE_ROUNDS_MOVED_ONLY = True


NO_IMPACTS = np.zeros((0, 7))  # ccd_pass without the hits' weights and normals


@dataclass(frozen=True)
class CollisionOptions:
    """How hard the collision pass works, the same for every scene (a run's `collision` config):
    the Gauss-Seidel passes of each stage and the impact-zone rounds before it gives up. The
    distances and friction are the scene's (SelfCollisionParams takes both)."""

    proximity_passes: int = 2  # Gauss-Seidel passes of the repulsion
    # Gauss-Seidel CCD passes before rigid impact zones. A pass after the first tests only the
    # pairs the previous one moved, so a pass is cheap; a zone round that merges a hundred nodes
    # is not. On karate (view-dependent, 150 frames, seeds 0 and 2) 3 passes left enough for
    # 216 and 424 zone rounds, 8 passes 47 and 31: the collision phase 1.8x and 3.1x faster,
    # adaptive's within noise; the stability suite passes 85 of 85 with 8 as with 3.
    ccd_passes: int = 8
    # impact-zone rounds before giving up (the record says what is left). Rounds run only while
    # collisions remain. Once round-off had moved the stability cases' trajectories (a faster
    # element-Hessian projection), 12 rounds left 7 pairs in one frame of karate_2x and 24 left
    # one in one_frame_step; with 48 neither leaves any.
    max_zone_passes: int = 48

    def __post_init__(self):
        for name in ("proximity_passes", "ccd_passes", "max_zone_passes"):
            v = getattr(self, name)
            if isinstance(v, bool) or int(v) != v or v < 0:
                raise ValueError(f"collision.{name} must be an integer >= 0, got {v!r}")


@dataclass(frozen=True)
class SelfCollisionParams:
    thickness: float  # m, distance kept between cloth surfaces (and from obstacles)
    friction: float = 0.3  # Coulomb coefficient, cloth against cloth
    # m kept between two cloth primitives where it differs from `thickness` (at most `thickness`:
    # the broad phase pads by it; obstacle pairs keep `thickness`); None: `thickness`
    self_thickness: float | None = None
    # the passes and rounds of each stage: CollisionOptions (its defaults)
    proximity_passes: int = CollisionOptions.proximity_passes
    ccd_passes: int = CollisionOptions.ccd_passes
    max_zone_passes: int = CollisionOptions.max_zone_passes

    def __post_init__(self):
        if not self.thickness > 0:
            raise ValueError(f"self-collision thickness must be > 0, got {self.thickness}")
        if self.self_thickness is not None and not self.self_thickness > 0:
            raise ValueError(f"self-collision self_thickness must be > 0 or None, got {self.self_thickness}")
        if self.friction < 0:
            raise ValueError(f"self-collision friction must be >= 0, got {self.friction}")
        for name in ("proximity_passes", "ccd_passes", "max_zone_passes"):
            if int(getattr(self, name)) < 0:
                raise ValueError(f"self-collision {name} must be >= 0, got {getattr(self, name)}")


def resolve_self_collisions(face_nodes, face_edges, edge_nodes, x0, x1, node_m, pinned,
                            params: SelfCollisionParams, *, n_fixed_faces: int = 0, first_fixed=None,
                            self_pairs: bool = True, skip=None, trees: dict | None = None) -> dict:
    """Make the step x0 -> x1 free of cloth self-collisions (modifies x1 in place).

    Returns the record: proximity pairs, CCD collisions found in the first pass, CCD passes,
    impact zones and their rounds, and the collisions left when every bound was reached.

    Obstacles (see `resolve_collisions_with_obstacles`, which builds these arguments): the last
    `n_fixed_faces` faces are obstacle triangles on the pinned nodes from `first_fixed` on;
    pairs are taken between them and the cloth, and within the cloth only if `self_pairs`;
    `skip` (N,) bool: cloth nodes left out of the pairs with obstacle nodes. The record then
    counts the pairs with an obstacle node apart (OBSTACLE_RECORD); the self_ keys count the rest.
    `trees`: the obstacles' tree kept from pass to pass (see `resolve_collisions_with_obstacles`).
    """
    h = params.thickness  # pairs with an obstacle node; the broad phase pads by it
    h_self = h if params.self_thickness is None else min(float(params.self_thickness), h)  # cloth-cloth pairs
    inv_m = np.where(pinned, 0.0, 1.0 / node_m)
    N = x0.shape[0]
    first_fixed = N if first_fixed is None else int(first_fixed)
    skip = np.zeros(N, dtype=np.bool_) if skip is None else np.ascontiguousarray(skip, dtype=np.bool_)
    stats = dict(SELF_COLLISION_RECORD)
    if n_fixed_faces:
        stats.update(OBSTACLE_RECORD)
    if face_nodes.shape[0] < 2:
        return stats

    owners = owner_faces(face_nodes, face_edges, N, edge_nodes.shape[0])
    # The face pairs of the broad phase, found once over x0 -> x1 padded by h and reused by every
    # later query while no coordinate of x1 has moved more than h - pad since: a query's swept
    # boxes then lie within the reference ones grown by that move, so every face pair within
    # 2 pad now was within 2 h then. The reused pairs hold the query's own, and the vertex-face
    # and edge-edge pairs, filtered by their own boxes and sorted, are exactly the query's.
    ref = [None, None]  # [face pairs, x1 when they were found]
    obstacle_cache = {}  # the obstacle triangles' tree, built once: their nodes never move in the pass

    def pairs(xa, xb, pad, only=None):
        """The query's pairs; with `only` (nodes flagged), just those of face pairs with a flagged node
        (a later CCD pass tests nothing else)."""
        fp, x_ref = ref
        if fp is None or not REUSE_BROAD_PHASE or not float(np.max(np.abs(x1 - x_ref), initial=0.0)) <= h - pad:
            boxes = swept_boxes(face_nodes, edge_nodes, x0, x1)
            fp = ref[0] = overlapping_face_pairs(boxes[2], boxes[3], h, n_fixed_faces, self_pairs, obstacle_cache,
                                                 trees)
            ref[1] = x1.copy()
        if only is not None and REUSE_BROAD_PHASE:
            flagged = only[face_nodes].any(axis=1)
            fp = fp[flagged[fp[:, 0]] | flagged[fp[:, 1]]]
        boxes = swept_boxes(face_nodes, edge_nodes, xa, xb)
        return primitive_pairs(fp, face_nodes, face_edges, edge_nodes, boxes, owners, pad, inv_m, first_fixed, skip)

    def count(key_self, key_obstacle, hits, n):
        n_obstacle = int(np.count_nonzero((hits[:n] >= first_fixed).any(axis=1))) if n_fixed_faces else 0
        stats[key_self] = int(n) - n_obstacle
        if n_fixed_faces:
            stats[key_obstacle] = n_obstacle

    eta = CCD_ETA_FRACTION * h_self  # the thinner layer's: a touch of either kind, a correction that
    sep = CCD_SEPARATION_FRACTION * h_self  # puts no pair beyond its own thickness
    # 1. proximity at the proposed end positions (its pairs: the reference ones, `pairs`)
    if params.proximity_passes > 0:
        vf, ee = pairs(x1, None, h)
        n_self, n_obstacle = proximity_repulsion(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, h, h_self,
                                                 params.friction, int(params.proximity_passes), first_fixed)
        stats["self_proximity"] = int(n_self)
        if n_fixed_faces:
            stats["obstacle_proximity"] = int(n_obstacle)
    # 2. CCD passes with corrections
    vf, ee = pairs(x0, x1, eta)
    hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    moved = np.zeros(N + 1, dtype=bool)  # first pass: every pair
    for p in range(int(params.ccd_passes)):
        n = ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, True, hits, moved, NO_IMPACTS)
        moved[-1] = True  # later passes: only pairs with a node this pass moved
        if p == 0:
            count("self_ccd_hits", "obstacle_ccd_hits", hits, n)
        if n == 0:
            return stats
        stats["self_ccd_passes"] = p + 1
        # the next CCD pass tests only pairs with a node this one moved; the impact zones, every pair
        vf, ee = pairs(x0, x1, eta, moved[:N] if p + 1 < int(params.ccd_passes) else None)
        hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    # 3. impact zones: rigid, or projected where they hold obstacle nodes
    parent = np.arange(N)
    in_zone = np.zeros(N, dtype=bool)
    x_zone = x1.copy()  # where the zones' projections start from: the positions before any zone
    zone_hits, zone_impacts = np.zeros((0, 4), dtype=np.int64), np.zeros((0, 7))
    for r in range(int(params.max_zone_passes) + 1):
        impacts = np.zeros((hits.shape[0], 7)) if n_fixed_faces else NO_IMPACTS
        n = ccd_pass(vf, ee, face_nodes, edge_nodes, x0, x1, inv_m, eta, sep, False, hits,
                     np.zeros(N + 1, dtype=bool), impacts)  # every pair: the zones moved them
        if n == 0:
            break
        if r == int(params.max_zone_passes):
            count("self_collisions_left", "obstacle_collisions_left", hits, n)
            break
        stats["impact_zone_rounds"] = r + 1
        x_round = x1.copy()
        zones = merge_zones(parent, in_zone, hits[:n])
        stats["impact_zones"] = len(zones)
        if n_fixed_faces:
            zone_hits = np.vstack([zone_hits, hits[:n]])
            zone_impacts = np.vstack([zone_impacts, impacts[:n]])
            zone_of = np.full(N, -1)  # each node's zone this round: which impacts are whose
            for k, zone in enumerate(zones):
                zone_of[zone] = k
            hit_zone = zone_of[zone_hits[:, 0]]  # (an impact's four nodes share one zone)
        for k, zone in enumerate(zones):
            if n_fixed_faces and zone[-1] >= first_fixed:  # (zones are sorted) an obstacle node in it
                # the best rigid fit of a deforming body's nodes (fingers bending) leaves
                # collisions round after round: separate every impact of the zone so far, from
                # the zone's positions before any zone moved it
                x1[zone] = x_zone[zone]
                inelastic_projection(x1, inv_m, zone_hits, zone_impacts, np.flatnonzero(hit_zone == k), sep,
                                     PROJECTION_SWEEPS, PROJECTION_TOLERANCE)
            else:
                rigid_motion(x0, x1, node_m, pinned, zone)
        # The next round tests only the pairs with a node this round moved (its end position
        # changed in any bit) or with a node of this round's hits: every other pair has the
        # motion it had when a round last tested it and found it free (a non-responding pass
        # tests each pair on its own), so the hits, in the same order, are those of every pair.
        changed = np.any(x1 != x_round, axis=1)
        changed[hits[:n].reshape(-1)] = True
        vf, ee = pairs(x0, x1, eta, changed if ZONE_ROUNDS_MOVED_ONLY else None)
        hits = np.empty((vf.shape[0] + ee.shape[0], 4), dtype=np.int64)
    return stats


def resolve_collisions_with_obstacles(face_nodes, face_edges, edge_nodes, x0, x1, node_m, pinned,
                                      params: SelfCollisionParams, obstacles, *, self_pairs: bool = True,
                                      skip=None, trees: dict | None = None) -> dict:
    """Make the step x0 -> x1 of the cloth free of collisions with triangle-mesh obstacles (and,
    with `self_pairs`, with itself, in the same pass), modifying x1 in place; the obstacles
    do not move.

    obstacles: [(y0 (V, 3), y1 (V, 3), faces (G, 3), face_edges (G, 3), edge_nodes (E, 2)), ...],
    each obstacle's vertex positions at the step's start and end (linear in between) and its
    topology (cloth.collision.meshobstacle.TriangleMeshObstacle.collision_topology). skip (n,) bool:
    cloth nodes to leave out of the cloth-obstacle pairs (e.g. found inside an obstacle at the
    step's start, where keeping them on their starting side would hold them in). trees: a dict the
    caller keeps from pass to pass, where the obstacles' broad-phase tree is kept and refitted
    (cloth.collision.candidates.obstacle_tree). Returns the record of `resolve_self_collisions`
    with OBSTACLE_RECORD.
    """
    if not len(obstacles) and not self_pairs:
        return {**SELF_COLLISION_RECORD, **OBSTACLE_RECORD}
    n, E = x0.shape[0], edge_nodes.shape[0]
    fn, fe = [np.asarray(face_nodes, np.int64)], [np.asarray(face_edges, np.int64)]
    en = [np.asarray(edge_nodes, np.int64)]
    X0, X1 = [x0], [x1]
    node_off, edge_off, n_fixed = n, E, 0
    for y0, y1, faces, f_edges, e_nodes in obstacles:
        fn.append(np.asarray(faces, np.int64) + node_off)
        fe.append(np.asarray(f_edges, np.int64) + edge_off)
        en.append(np.asarray(e_nodes, np.int64) + node_off)
        X0.append(np.asarray(y0, np.float64))
        X1.append(np.asarray(y1, np.float64))
        node_off += X0[-1].shape[0]
        edge_off += en[-1].shape[0]
        n_fixed += fn[-1].shape[0]
    extra = node_off - n
    x0_all, x1_all = np.ascontiguousarray(np.vstack(X0)), np.ascontiguousarray(np.vstack(X1))
    stats = resolve_self_collisions(
        np.ascontiguousarray(np.vstack(fn)), np.ascontiguousarray(np.vstack(fe)), np.ascontiguousarray(np.vstack(en)),
        x0_all, x1_all, np.concatenate([node_m, np.ones(extra)]), np.concatenate([pinned, np.ones(extra, dtype=bool)]),
        params, n_fixed_faces=n_fixed, first_fixed=n, self_pairs=self_pairs,
        skip=None if skip is None else np.concatenate([np.asarray(skip, dtype=bool), np.zeros(extra, dtype=bool)]),
        trees=trees)
    x1[:] = x1_all[:n]
    return stats
