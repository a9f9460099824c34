"""Schemas of the per-frame record (one row of frames.parquet): the columns each stage fills, and
their values in a frame where the stage did nothing. Each stage's code fills its own columns; the
frame loop starts every record from these, so that every mode and scene writes the same columns.
"""

from __future__ import annotations

# Phases timed in every frame record (seconds of wall time, column time_<phase>_s).
PHASES = ("sizing", "remesh", "physics", "solve", "collisions", "io", "other")
# The phases of the simulation itself (untangling is timed under collisions): their sum is the
# column sim_s, the paper's Time/Frame. I/O (time_io_s) and the rest (time_other_s: the record's
# own counts, view counts) are recorded beside it, never inside it.
SIM_PHASES = ("sizing", "remesh", "physics", "solve", "collisions")
# The collisions phase in its parts (column time_collisions_<part>_s; they sum to time_collisions_s):
# contacts, finding the obstacle contacts each step constrains; projection, moving nodes out of the
# obstacles after the step; pass, the step's collision pass (proximity, continuous detection, impact
# zones: cloth-cloth, and cloth-mesh obstacle with obstacle_ccd); untangle, removing crossings (of
# the start state, after a remesh, after a pass that gave up).
COLLISION_PARTS = ("contacts", "projection", "pass", "untangle")

# The remesh stage (NaN or 0 in frames without a remesh, and in mode=nonadaptive).
REMESH_RECORD = {"remeshed": 0, "remesh_splits": 0, "remesh_collapses": 0, "remesh_flips": 0,
                 "remesh_nodes_pushed_out": 0, "remesh_max_depth_m": 0.0,
                 # nodes exempt from obstacle contact after the remesh (made inside an obstacle, or still
                 # inside since: cloth.remeshing.adaptive.mark_passing)
                 "remesh_nodes_passing": 0,
                 # nodes put back where the remesh left them: their push-out or pop-filter move made a face
                 # cross a triangle-mesh obstacle (cloth.remeshing.adaptive.keep_obstacles_uncrossed)
                 "remesh_obstacle_moves_undone": 0,
                 "pop_energy_before_j": float("nan"), "pop_energy_after_j": float("nan"),
                 "pop_iterations": 0,
                 "pop_reverted": 0,  # pop filter rounds whose minimum lay past a node's edges: left as remeshed
                 "remesh_ccd_hits": 0, "remesh_guard_rounds": 0, "remesh_frozen_nodes": 0,
                 "remesh_guard_refused": 0,  # guard redos dropped: they made a face below the quality floor
                 # the guard's redos all crossed: 1, splits alone; 2, no remesh (cloth.remeshing.adaptive)
                 "remesh_guard_fallback": 0,
                 # the sizing field at its bounds (cloth.remeshing.sizing.sizing_at_bounds)
                 "faces_sized": 0, "faces_at_size_min": 0, "faces_at_size_max": 0, "edge_at_size_min_m": float("nan")}

# The view-dependent sizing (NaN in the other modes). faces_occluded: faces in frame and facing the
# camera that view.occlusion found hidden at the image's camera (tau = 0), so sized as back-facing
# (0 with view.occlusion off and in the other modes).
VIEW_RECORD = {"view_factor_min": float("nan"), "view_factor_mean": float("nan"), "view_factor_max": float("nan"),
               "contact_floor_faces": 0, "faces_occluded": 0,
               # mode=viewdep, a character wholly beyond the margin (cloth.view.viewdep): 1 when so,
               # and 1 when its remesh was skipped because the last one there changed nothing
               "character_out_of_view": 0, "remesh_skipped": 0}

# One collision pass of a step (cloth.collision.selfcollision): cloth-cloth pairs (self_*) and,
# with triangle-mesh obstacles in the same pass, cloth-obstacle pairs (obstacle_*).
SELF_COLLISION_RECORD = {"self_proximity": 0, "self_ccd_hits": 0, "self_ccd_passes": 0, "impact_zones": 0,
                         "impact_zone_rounds": 0, "self_collisions_left": 0}
OBSTACLE_RECORD = {"obstacle_proximity": 0, "obstacle_ccd_hits": 0, "obstacle_collisions_left": 0}

# The untangling after a remesh (cloth.collision.untangle).
UNTANGLE_RECORD = {"intersections_found": 0, "untangle_iterations": 0, "intersections_left": 0,
                   "intersection_depth_m": 0.0, "intersection_length_m": 0.0}

# Strain limiting after each step (cloth.physics.strainlimiting), the frame's worst step: its
# Newton steps and the largest violation it left (a principal stretch beyond the material's
# strain_limits, dimensionless). Zero in scenes without the effect.
STRAIN_LIMIT_RECORD = {"strain_limit_iterations": 0, "strain_violation_max": 0.0}

# The frame's collision columns: zero in scenes without the effects. untangles: the untanglings
# the frame ran (of the start state, after a remesh, after a step whose collision pass gave up);
# the UNTANGLE_RECORD columns then give the most crossings found, the iterations of all of them,
# and what the last one left.
COLLISION_RECORD = {"self_velocity_clamped": 0, "untangles": 0, **SELF_COLLISION_RECORD, **OBSTACLE_RECORD,
                    **UNTANGLE_RECORD}

# Step control (cloth.stepcontrol: MAX_STEP_HALVINGS): the checks a step must pass, in the order
# they are tried (a non-finite state; a node over max_speed; the kinetic energy jumping by more than
# KE_JUMP_FACTOR; a collision pass that gave up), and per frame the steps rejected (undone and
# taken again as two of half the length), of each kind, and the shortest step taken (s; the
# frame's step when none was rejected).
STEP_CHECKS = ("non_finite", "speed", "kinetic_energy", "collisions")
STEP_RECORD = {"steps_rejected": 0, **{f"steps_rejected_{c}": 0 for c in STEP_CHECKS}, "dt_min_s": float("nan")}
