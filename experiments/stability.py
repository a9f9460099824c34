"""The stability suite: hard cases that must run to the end with every value finite, the kinetic
energy bounded, no intersection left and no face below the quality bound.

    python -m experiments.stability [--scale paper] [--frames 100] [--cases crushed_sheet karate_2x] [--out DIR]

runs the cases (the larger versions with --scale paper) and writes
<out>/<timestamp>/table.csv and table.md (default out: results/stability) (one row per case: the
checks and the figures behind them). tests/stability/ runs the same cases at scale=small with
fewer frames.

Each case is a scene and mode with a few overrides:

- one_frame_step: a time step of one whole frame (steps_per_frame = 1);
- stiff_material: a material 100x stiffer in stretch and bending;
- nu_out_0.001: extreme coarsening out of view (nu_out = 0.001);
- buckling_k1, buckling_k50: buckling compensation at k = 1 and k = 50;
- cut_every_3_frames: a jump cut every 3 frames (two shots, alternating);
- orbit_1s: a camera orbiting the cloth once per second;
- karate_2x: the karate motion at twice its speed (layered skirts with self-collision);
- crushed_sheet: a strip collapsed into folds and pressed between two planes (dense self-contact);
- crushed_sheet_fixed: the same on a fixed mesh of light, small faces (48 cells along the strip
  at scale=small, 96 at scale=paper), where a dense pile once diverged (cloth.physics.membrane);
- thin_triangles: layered sheets made of very thin input triangles (cells 12x longer than wide);
- thin_garment: the dancer's circle skirt made of very thin input triangles (cells 12x longer
  across than around: one ring of 0.55 m x 3.7 cm cells at scale=small), adaptive, with
  self-collision.
"""

from __future__ import annotations

import argparse
from dataclasses import dataclass
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from hydra import compose, initialize_config_dir
from omegaconf import open_dict

from cloth.collision.untangle import find_intersections
from cloth.io.manifest import write_text_atomic
from experiments.build import build_simulation
from experiments.compare_modes import markdown

CONF = str(Path(__file__).resolve().parents[1] / "conf")

# The remesher keeps the aspect 12 sqrt(3) A / P^2 of the faces it makes at or above aspect_min
# = 0.2; the recorded quality 4 sqrt(3) A / sum(l^2) is at least a third of that aspect
# (sum(l^2) <= P^2), so no remeshed face may fall below:
QUALITY_MIN = 0.2 / 3
# Kinetic energy bound: the cloth cannot move faster on average than a free fall from
# FALL_HEIGHT_M, or than the body's fastest parts (a kick at twice speed: BODY_SPEED_M_S).
FALL_HEIGHT_M = 1.0
BODY_SPEED_M_S = 12.0
G = 9.81


@dataclass
class Case:
    name: str
    overrides: list
    speed_bound_m_s: float = float(np.sqrt(2 * G * FALL_HEIGHT_M))
    cut_every: int = 0  # frames between jump cuts (0: the camera config as it is)
    frames_small: int = 20
    what: str = ""


SHEETS = ["scene=layered_sheets"]
VIEW = ["mode=viewdep", "camera=sheet_half"]
CASES = [
    Case("one_frame_step", SHEETS + ["mode=adaptive", "scene.params.steps_per_frame=1"],
         what="time step of one frame"),
    Case("stiff_material", SHEETS + ["mode=adaptive", "material.youngs_modulus=2.0e5",
                                      "material.bending_stiffness=5.0e-4"], what="material 100x stiffer"),
    Case("nu_out_0.001", SHEETS + VIEW + ["mode.view.nu_out=0.001"], what="extreme coarsening out of view"),
    Case("buckling_k1", SHEETS + VIEW + ["mode.buckling.k=1"], what="buckling compensation k = 1"),
    Case("buckling_k50", SHEETS + VIEW + ["mode.buckling.k=50"], what="buckling compensation k = 50"),
    Case("cut_every_3_frames", SHEETS + ["mode=viewdep", "camera=sheet_cut"], cut_every=3,
         what="a jump cut every 3 frames"),
    Case("orbit_1s", SHEETS + ["mode=viewdep", "camera=orbit", "camera.period_s=1.0", "camera.radius=1.0",
                               "camera.height=0.6", "camera.center=[0.0,0.0,0.1]"],
         what="camera orbiting once per second"),
    Case("karate_2x", ["scene=karate", "mode=adaptive", "camera=none", "scene.params.speed=2.0",
                       "scene.params.settle=0.2", "scene.params.blend_in=0.4"],
         # 55 frames (2.2 s) at twice speed reach past the front kick (t = 1.4 s) and the half turn (1.7-2.1 s)
         speed_bound_m_s=BODY_SPEED_M_S, frames_small=55, what="karate at twice its speed"),
    Case("crushed_sheet", ["scene=crushed_sheet", "mode=adaptive"], frames_small=40,
         what="strip folded and pressed between two planes"),
    Case("crushed_sheet_fixed", ["scene=crushed_sheet", "mode=nonadaptive", "scene.scales.small.resolution=48"],
         frames_small=40, what="crushed sheet on a fixed mesh of light, small faces"),
    Case("thin_triangles", SHEETS + ["mode=adaptive", "scene.params.cell_aspect=12"],
         what="input mesh of very thin triangles"),
    # with self_collision: as declared, the dancer's skirt may fold through itself (242 crossing
    # face pairs after 20 frames of the plain scene), and this case checks that none is left
    Case("thin_garment", ["scene=solo_dancer", "mode=adaptive", "camera=none", "scene.params.cell_aspect=12",
                          "scene.effects=[membrane,bending,gravity,damping,obstacles,self_collision]"],
         speed_bound_m_s=BODY_SPEED_M_S, what="a dress made of very thin input triangles"),
]
CASE_NAMES = [c.name for c in CASES]


def case(name: str) -> Case:
    for c in CASES:
        if c.name == name:
            return c
    raise ValueError(f"unknown stability case {name!r}; known: {CASE_NAMES}")


def _cfg(c: Case, scale: str):
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=c.overrides + [f"scale={scale}"])
    if c.cut_every:
        shots = list(cfg.camera.shots)
        frame_time = float(cfg.scene.params.frame_time)
        horizon = 1000
        with open_dict(cfg):
            cfg.camera.shots = [{**dict(shots[k % len(shots)]), "start": k * c.cut_every * frame_time}
                                for k in range(horizon // c.cut_every)]
    return cfg


def run_case(c: Case, frames: int, scale: str = "small") -> dict:
    """Run one case; return its checks and figures. Raises nothing for a bad run: a run that
    stops (non-finite values) is reported with ok = False and the error."""
    sim = build_simulation(_cfg(c, scale))[0]
    row = {"case": c.name, "what": c.what, "frames": frames, "error": ""}
    records = []
    try:
        for _ in range(frames):
            records.append(sim.advance_frame())
    except Exception as exc:  # noqa: BLE001 - the record says why the case stopped
        row["error"] = f"{type(exc).__name__}: {exc}"
    df = pd.DataFrame(records)
    mesh = sim.mesh
    mass = float(mesh.node_m.sum())
    ke_bound = 0.5 * mass * c.speed_bound_m_s ** 2
    physical = ["kinetic_energy_j", "potential_energy_j", "max_speed_m_s", "min_face_quality"]
    row.update(
        frames_run=len(df),
        finite=bool(np.all(np.isfinite(mesh.node_x)) and np.all(np.isfinite(mesh.node_v))
                    and np.all(np.isfinite(df[physical].to_numpy(dtype=float)))),
        max_kinetic_energy_j=float(df.kinetic_energy_j.max()) if len(df) else np.nan,
        kinetic_energy_bound_j=ke_bound,
        intersections_left_max=int(df.intersections_left.max()) if len(df) else -1,
        self_collisions_left_max=int(df.self_collisions_left.max()) if len(df) else -1,
        crossings_at_end=len(find_intersections(mesh.face_nodes, mesh.node_x)[0]),
        min_face_quality=float(df.min_face_quality.min()) if len(df) else np.nan,
        faces_max=int(df.faces.max()) if len(df) else 0,
        s_per_frame=float(df.sim_s.mean()) if len(df) else np.nan,
        collision_share=float(df.time_collisions_s.sum() / df.sim_s.sum()) if len(df) else np.nan,
    )
    row["ok"] = bool(not row["error"] and row["frames_run"] == frames and row["finite"]
                     and row["max_kinetic_energy_j"] <= ke_bound and row["intersections_left_max"] == 0
                     and row["self_collisions_left_max"] == 0 and row["crossings_at_end"] == 0
                     and row["min_face_quality"] >= QUALITY_MIN)
    return row


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scale", default="paper")
    ap.add_argument("--frames", type=int, default=100)
    ap.add_argument("--cases", nargs="+", default=CASE_NAMES, choices=CASE_NAMES)
    ap.add_argument("--out", type=Path, default=Path("results/stability"))
    args = ap.parse_args(argv)
    out = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for name in args.cases:
        rows.append(run_case(case(name), args.frames, args.scale))
        print(f"{name:20s} ok={rows[-1]['ok']}  {rows[-1]['error']}", flush=True)
        table = pd.DataFrame(rows)  # written after every case: a killed run keeps what it had
        write_text_atomic(out / "table.csv", table.to_csv(index=False))
        write_text_atomic(out / "table.md", markdown(table.drop(columns=["what"])))
    print(table.drop(columns=["what"]).to_string(index=False))
    print(f"\nresults in {out}")


if __name__ == "__main__":
    main()
