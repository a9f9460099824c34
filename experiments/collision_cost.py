"""What collisions cost: the share of frame time spent in contact, self-collision and untangling,
and how it grows with the number of faces.

    python -m experiments.collision_cost [--frames 40] [--resolutions 24 48 96]

Runs `crushed_sheet` (nonadaptive, one run per resolution: dense self-contact at a fixed face
count; then adaptive, where untangling and the remesh's crossing guard add to it) and
`solo_dancer` (adaptive, as declared and with self_collision added to its effects; a run that
diverges is measured over the frames before it) and prints one row per run: faces, seconds per
frame, seconds per frame in collisions (time_collisions_s: obstacle contact, self-collision
within the steps and untangling after remeshes) and its share, with the growth of the collision
time against the growth of faces between consecutive resolutions.
Writes <out>/<timestamp>/table.csv (--out, default results/collision_cost).
"""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from hydra import compose, initialize_config_dir

from cloth.io.manifest import write_text_atomic
from cloth.simulation import SimulationDiverged
from experiments.build import build_simulation

CONF = str(Path(__file__).resolve().parents[1] / "conf")


def run(overrides: list, frames: int, warmup: int = 1) -> dict:
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    sim = build_simulation(cfg)[0]
    rows, error = [], ""
    try:
        for _ in range(frames):
            rows.append(sim.advance_frame())
    except SimulationDiverged as exc:  # the frames before it still measure the cost
        error = str(exc)
    df = pd.DataFrame(rows).iloc[warmup:]
    return {"frames_run": len(rows), "error": error, "faces_mean": float(df.faces.mean()),
            "s_per_frame": float(df.sim_s.mean()),
            "collision_s_per_frame": float(df.time_collisions_s.mean()),
            "collision_share": float(df.time_collisions_s.sum() / df.sim_s.sum()),
            "self_proximity_max": int(df.self_proximity.max()),
            "impact_zone_rounds_max": int(df.impact_zone_rounds.max()),
            "intersections_found_max": int(df.intersections_found.max()),
            "left_max": int(max(df.intersections_left.max(), df.self_collisions_left.max()))}


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--frames", type=int, default=40)
    ap.add_argument("--resolutions", type=int, nargs="+", default=[24, 48, 96])
    ap.add_argument("--dancer-frames", type=int, default=60)
    ap.add_argument("--out", type=Path, default=Path("results/collision_cost"))
    args = ap.parse_args(argv)
    rows = []
    for n in args.resolutions:
        r = run(["scene=crushed_sheet", "mode=nonadaptive", f"scene.scales.small.resolution={n}"], args.frames)
        rows.append({"run": f"crushed_sheet n={n}", **r})
        print(rows[-1], flush=True)
    r = run(["scene=crushed_sheet", "mode=adaptive"], args.frames)
    rows.append({"run": "crushed_sheet adaptive", **r})
    print(rows[-1], flush=True)
    r = run(["scene=solo_dancer", "mode=adaptive", "camera=none"], args.dancer_frames)
    rows.append({"run": "solo_dancer adaptive (as declared: body contact only)", **r})
    print(rows[-1], flush=True)
    effects = "[membrane,bending,gravity,damping,obstacles,self_collision]"
    r = run(["scene=solo_dancer", "mode=adaptive", "camera=none", f"scene.effects={effects}"], args.dancer_frames)
    rows.append({"run": "solo_dancer adaptive + self_collision", **r})
    print(rows[-1], flush=True)
    t = pd.DataFrame(rows)
    crushed = t.iloc[: len(args.resolutions)]
    growth = np.log(crushed.collision_s_per_frame.to_numpy()[1:] / crushed.collision_s_per_frame.to_numpy()[:-1]) / \
        np.log(crushed.faces_mean.to_numpy()[1:] / crushed.faces_mean.to_numpy()[:-1])
    t["collision_time_exponent"] = [np.nan] + list(growth) + [np.nan] * (len(t) - len(crushed))
    out = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out / "table.csv", t.to_csv(index=False))
    print(t.to_string(index=False))
    print(f"\nresults in {out}")


if __name__ == "__main__":
    main()
