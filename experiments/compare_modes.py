"""Measure the three modes on the same scene and camera, in one run (the adaptive and view-dependent
issues, item 7 of each).

    python -m experiments.compare_modes [--scenes sheet_on_sphere flag] [--modes nonadaptive adaptive viewdep]
                                        [--frames 60] [--scale small] [--camera scene=camera ...]

The nonadaptive mesh of each scale preset has the edge length of the adaptive's finest edge
(scene.scales.<scale>.sizing.size_min). Every mode sees the same camera (DEFAULT_CAMERAS, a camera
that frames part of the cloth, or the scene's own camera work for the character scenes); only
mode=viewdep uses it for sizing, the others for the records (faces in view). Writes
<out>/<timestamp>/frames.parquet (--out, default results/compare_modes) (every frame of every
run) and table.csv / table.md (faces, faces in view and time per frame, min/max/mean; speed-ups
over nonadaptive and over adaptive; share of frame time per phase) and prints the table.
"""

from __future__ import annotations

import argparse
from datetime import datetime
from pathlib import Path

import pandas as pd
from hydra import compose, initialize_config_dir

from cloth.io.manifest import environment_manifest, write_json_atomic, write_text_atomic
from experiments.analysis.tables import markdown
from experiments.build import build_simulation

CONF = str(Path(__file__).resolve().parents[1] / "conf")
DEFAULT_CAMERAS = {"sheet_on_sphere": "sheet_half", "flag": "flag_partial"}
PHASE_SHARES = {"sizing": ["time_sizing_s"], "remesh": ["time_remesh_s"],
                "physics": ["time_physics_s", "time_solve_s"], "collisions": ["time_collisions_s"]}


def run(scene: str, mode: str, frames: int, scale: str, camera: str | None = None) -> pd.DataFrame:
    """One run; `camera` None keeps the scene's own camera (the character scenes bring theirs)."""
    overrides = [f"scene={scene}", f"mode={mode}", f"scale={scale}"] + ([f"camera={camera}"] if camera else [])
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    sim = build_simulation(cfg)[0]
    rows = [sim.advance_frame() for _ in range(frames)]
    df = pd.DataFrame(rows)
    df["scene"], df["mode"] = scene, mode
    return df


def table(frames: pd.DataFrame) -> pd.DataFrame:
    out = []
    for (scene, mode), d in frames.groupby(["scene", "mode"], sort=False):
        row = {"scene": scene, "mode": mode,
               "faces_min": d.faces.min(), "faces_max": d.faces.max(), "faces_mean": d.faces.mean(),
               "faces_in_view_mean": d.faces_in_view.mean(),
               "s_per_frame_min": d.sim_s.min(), "s_per_frame_max": d.sim_s.max(),
               "s_per_frame_mean": d.sim_s.mean()}
        for phase, cols in PHASE_SHARES.items():
            row[f"share_{phase}"] = d[cols].sum(axis=1).sum() / d.sim_s.sum()
        out.append(row)
    t = pd.DataFrame(out)
    for ref in ("nonadaptive", "adaptive"):
        base = t[t["mode"] == ref].set_index("scene")["s_per_frame_mean"]
        t[f"speedup_vs_{ref}"] = base.reindex(t["scene"]).to_numpy() / t["s_per_frame_mean"]
    return t


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--scenes", nargs="+", default=["sheet_on_sphere", "flag"])
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--scale", default="small")
    ap.add_argument("--modes", nargs="+", default=["nonadaptive", "adaptive", "viewdep"])
    ap.add_argument("--camera", nargs="*", default=[], metavar="SCENE=CAMERA",
                    help=f"camera per scene (conf/camera/); defaults: {DEFAULT_CAMERAS}")
    ap.add_argument("--warmup", type=int, default=1, help="frames excluded from the table (compilation)")
    ap.add_argument("--out", type=Path, default=Path("results/compare_modes"))
    args = ap.parse_args(argv)
    if args.frames <= args.warmup:
        ap.error(f"--frames ({args.frames}) must exceed --warmup ({args.warmup})")
    cameras = dict(DEFAULT_CAMERAS)
    for item in args.camera:
        scene, sep, cam = item.partition("=")
        if not sep:
            ap.error(f"--camera takes SCENE=CAMERA, got {item!r}")
        cameras[scene] = cam
    crowds = [s for s in args.scenes if s == "multiple_dancers"]
    if crowds:
        ap.error("a crowd is one simulation per character: run it with python -m experiments.run "
                 "scene=multiple_dancers mode=<mode>")
    out_dir = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out_dir / "manifest.json", environment_manifest(0))
    runs = []
    for scene in args.scenes:
        for mode in args.modes:
            df = run(scene, mode, args.frames, args.scale, cameras.get(scene))
            runs.append(df)
            print(f"{scene:16s} {mode:12s} done: {df.faces.mean():8.0f} faces, "
                  f"{df.sim_s.iloc[args.warmup:].mean():.3f} s/frame")
    frames = pd.concat(runs, ignore_index=True)
    frames.to_parquet(out_dir / "frames.parquet")
    t = table(frames[frames["frame"] > args.warmup])
    write_text_atomic(out_dir / "table.csv", t.to_csv(index=False))
    write_text_atomic(out_dir / "table.md", markdown(t))
    print(markdown(t))
    print(f"results in {out_dir}")


if __name__ == "__main__":
    main()
