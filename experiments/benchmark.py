"""Benchmark: time per implicit step of `sheet_on_sphere` at about 2k, 8k, 32k and 128k faces.

    python -m experiments.benchmark [--resolutions 32 64 128 256] [--frames 6] [--warmup 12]
                                    [--solver auto|cholesky|pcg|direct] [--out DIR]
                                    [--bending-hessian projected|gauss_newton|both] [--against REV]
    python -m experiments.benchmark --modes [--scene sheet_on_sphere] [--camera sheet_half]
                                    [--frames 20] [--warmup 10] [--out DIR]
    python -m experiments.benchmark --scene karate|solo_dancer|PATH/conf/sphere.json
                                    [--mode adaptive] [--scale small] [--frames 20] [--warmup 5]
                                    [--against REV] [KEY=VALUE ...]

`--modes` times the three modes on one scene (Hydra's config, `--scale`, small by default) at matched mean
faces: mode=adaptive runs first, and the fixed mesh's resolution_factor is set so that its faces
equal adaptive's mean; mode=viewdep runs with `--camera`. It prints and writes (`modes.csv`)
microseconds per face per step of every phase (sizing, remeshing with its pop filter, physics,
solve, collisions), so that the adaptive modes' overhead per face is visible, and the ratio of
adaptive's frame time to the fixed mesh's.

`--scene` without `--modes` times one scene as the runs of a study run it (Hydra's config: a
scene of `conf/scene/`, or an ARCSim configuration given as its .json path, run as `scene=arcsim`)
in `--mode` and prints microseconds per face per step of every phase, the collisions phase in its
parts (obstacle contacts, their projection, the collision pass, untangling), and the implicit
steps per frame against the scene's own (obstacle substeps and step control add steps); it
writes `scene.csv` and `summary.json`.

`--bending-hessian both` times every resolution with the projected bending Hessian and with the
Gauss-Newton one (solver.bending_hessian), one after the other on the same sheet, and prints the
ratio of their physics and step times at each resolution (projected over Gauss-Newton).

`--against REV` times a previous commit on the same sheets in the same run (with `--scene`: on the
same scene, REV's `--scene` benchmark first, per phase and collision part): for each resolution,
REV's own benchmark (its tree exported with `git archive` into a temporary folder and run there
as a subprocess, with the same frames, warm-up and solver) and then this tree's, one after the
other, so that both meet the same machine load; it prints REV's time over this tree's per phase
(above 1: this tree is faster) and writes `against.csv`.

A benchmark, not a test: it prints ratios measured in one run and writes
`<out>/<timestamp>/steps.csv` (default out: results/benchmark) (one row per resolution: seconds per step by phase,
microseconds per face per step, the share of step time outside compiled kernels and the
linear solver) and `summary.json` (the growth exponent of time with faces, from a log-log fit,
and the solver that ran). `--report PAGE.md` (the sheet and `--modes`) writes the printed tables
as a Markdown page stamped with the commit, the machine and the command (docs/benchmark.md).

Time inside compiled kernels is measured by wrapping every numba dispatcher that the Python
layer calls outside the linear solve (the wrappers add about a microsecond per call, a few dozen
calls per step); the solve's own time is its phase.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from datetime import datetime
from pathlib import Path

import numpy as np
import pandas as pd
from numba.core.registry import CPUDispatcher

import cloth.collision.contact
import cloth.collision.obstacles
import cloth.physics.assembly
import cloth.physics.forces
import cloth.physics.integrator
from cloth.core.material import Material
from cloth.core.records import COLLISION_PARTS, PHASES, SIM_PHASES
from cloth.io.manifest import environment_manifest, write_json_atomic, write_text_atomic
from cloth.physics.linsolve import BENDING_HESSIAN_DEFAULT, BENDING_HESSIANS, METHODS, SolverOptions, resolve_method
from cloth.scenes.registry import build_scene
from cloth.simulation import Simulation

COTTON = dict(name="cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3,
              bending_stiffness=5e-6, damping_mass=0.05, damping_stiffness=2e-3)
ROOT = Path(__file__).resolve().parents[1]
CONF = ROOT / "conf"
KERNEL_MODULES = (cloth.physics.assembly, cloth.collision.contact, cloth.physics.forces, cloth.physics.integrator,
                  cloth.collision.obstacles)


class KernelClock:
    """Accumulates wall time spent inside numba kernels called from Python."""

    def __init__(self):
        self.seconds = 0.0
        self._saved = []

    def install(self):
        for module in KERNEL_MODULES:
            for name, obj in list(vars(module).items()):
                if isinstance(obj, CPUDispatcher):
                    self._saved.append((module, name, obj))
                    setattr(module, name, self._wrap(obj))

    def uninstall(self):
        for module, name, obj in self._saved:
            setattr(module, name, obj)
        self._saved.clear()

    def _wrap(self, fn):
        def timed(*args):
            t0 = time.perf_counter()
            out = fn(*args)
            self.seconds += time.perf_counter() - t0
            return out
        return timed


def bench(resolution: int, frames: int, warmup: int, solver: SolverOptions) -> dict:
    # the benchmark's own step, 1/30 s frames of 4 steps (dt = 8.3 ms), as in the numbers it has
    # published; the scene's default (conf/scene/sheet_on_sphere.yaml) is 0.04 s of 8
    scene = build_scene("sheet_on_sphere", Material(**COTTON), resolution=resolution,
                        frame_time=1 / 30, steps_per_frame=4)
    sim = Simulation(scene, solver=solver)
    for _ in range(warmup):  # compile, and let the sheet reach the sphere (contacts active)
        sim.advance_frame()
    clock = KernelClock()
    clock.install()
    rows = []
    try:
        for _ in range(frames):
            rows.append(sim.advance_frame())
    finally:
        clock.uninstall()
    df = pd.DataFrame(rows)
    steps = frames * scene.steps_per_frame
    wall = df["wall_s"].sum()
    out = {"resolution": resolution, "faces": sim.mesh.n_faces, "nodes": sim.mesh.n_nodes,
           "solver": resolve_method(solver.method, 3 * sim.mesh.n_nodes), "bending_hessian": solver.bending_hessian,
           "steps": steps, "s_per_step": wall / steps}
    for p in PHASES:
        out[f"{p}_s_per_step"] = df[f"time_{p}_s"].sum() / steps
    out["us_per_face_per_step"] = 1e6 * wall / steps / sim.mesh.n_faces
    out["cg_iterations_per_step"] = df["solver_iterations"].sum() / steps
    out["solves_capped"] = int(df["solves_capped"].sum())
    out["kernel_s_per_step"] = clock.seconds / steps  # compiled kernels outside the solve
    solve_s = df["time_solve_s"].sum()
    out["share_outside_kernels_and_solver"] = max(0.0, 1.0 - (clock.seconds + solve_s) / wall)
    return out


def _time_mode(overrides: list[str], frames: int, warmup: int) -> pd.DataFrame:
    """The timed frames' records of one run built from conf/ with `overrides` (after `warmup`)."""
    from hydra import compose, initialize_config_dir  # noqa: PLC0415 - import cost: --modes only

    from experiments.build import build_simulation  # noqa: PLC0415 - import cost: --modes only

    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        cfg = compose(config_name="config", overrides=overrides)
    sim, _ = build_simulation(cfg)
    for _ in range(warmup):
        sim.advance_frame()
    df = pd.DataFrame([sim.advance_frame() for _ in range(frames)])
    df.attrs["scene_steps_per_frame"] = sim.scene.steps_per_frame  # what the scene asks for
    return df


def mode_row(mode: str, df: pd.DataFrame) -> dict:
    """Per-face-per-step cost of each phase of one mode's timed frames."""
    face_steps = float((df["faces"] * df["steps"]).sum())
    row = {"mode": mode, "faces_mean": float(df["faces"].mean()), "steps": int(df["steps"].sum()),
           "s_per_frame": float(df["sim_s"].mean())}
    for p in SIM_PHASES:
        row[f"{p}_us_per_face_step"] = 1e6 * float(df[f"time_{p}_s"].sum()) / face_steps
    for part in COLLISION_PARTS:
        row[f"collisions_{part}_us_per_face_step"] = 1e6 * float(df[f"time_collisions_{part}_s"].sum()) / face_steps
    row["us_per_face_step"] = 1e6 * float(df["sim_s"].sum()) / face_steps
    return row


def scene_overrides(scene: str) -> list[str]:
    """The overrides that select `scene`: a conf/scene/ name, or an ARCSim .json configuration."""
    if scene.endswith(".json"):
        return ["scene=arcsim", f"scene.params.conf={Path(scene).expanduser().resolve()}"]
    return [f"scene={scene}"]


def scene_error(scene: str) -> str | None:
    """Why `scene` (a conf/scene/ name or an ARCSim .json path) cannot run, or None."""
    if scene.endswith(".json"):
        return None if Path(scene).expanduser().is_file() else f"--scene {scene!r}: no such ARCSim configuration"
    if not (CONF / "scene" / f"{scene}.yaml").exists():
        return f"--scene {scene!r}: no conf/scene/{scene}.yaml (or give an ARCSim .json)"
    return None


def bench_scene(scene: str, mode: str, frames: int, warmup: int, extra: list[str], scale: str = "small") -> dict:
    """One scene in one mode: per-phase cost per face per step of `frames` frames after `warmup`."""
    overrides = [*scene_overrides(scene), f"mode={mode}", f"scale={scale}", *extra]
    df = _time_mode(overrides, frames, warmup)
    row = mode_row(mode, df)
    row.update(scene=scene, scale=scale, frames=frames, scene_steps_per_frame=df.attrs["scene_steps_per_frame"],
               steps_per_frame=float(df["steps"].mean()),
               steps_per_frame_max=int(df["steps"].max()), collision_share=float(df["time_collisions_s"].sum()
                                                                                  / df["sim_s"].sum()))
    return row


def bench_modes(scene: str, camera: str, frames: int, warmup: int, extra: list[str],
                scale: str = "small") -> pd.DataFrame:
    base = [f"scene={scene}", f"scale={scale}", *extra]
    probe = _time_mode([*base, "mode=nonadaptive"], 1, 0)  # the preset's fixed mesh: faces at factor 1
    adaptive = _time_mode([*base, "mode=adaptive"], frames, warmup)
    factor = float(np.sqrt(adaptive["faces"].mean() / probe["faces"].iloc[0]))
    fixed = _time_mode([*base, "mode=nonadaptive", f"resolution_factor={factor:.4f}"], frames, warmup)
    viewdep = _time_mode([*base, "mode=viewdep", f"camera={camera}"], frames, warmup)
    rows = [mode_row("nonadaptive", fixed), mode_row("adaptive", adaptive), mode_row("viewdep", viewdep)]
    out = pd.DataFrame(rows)
    out.attrs["resolution_factor"] = factor
    return out


def resolve_revision(rev: str) -> str:
    """The full commit of `rev` in this repository, or ValueError naming it."""
    done = subprocess.run(["git", "-C", str(ROOT), "rev-parse", "--verify", "--quiet", f"{rev}^{{commit}}"],
                          capture_output=True, text=True)
    if done.returncode != 0:
        raise ValueError(f"--against {rev!r}: not a commit of {ROOT}")
    return done.stdout.strip()


def export_revision(commit: str, dest: Path) -> Path:
    """Commit's tree written into `dest` (git archive), checked to import its own `cloth`."""
    dest.mkdir(parents=True, exist_ok=True)
    archive = subprocess.run(["git", "-C", str(ROOT), "archive", "--format=tar", commit],
                             capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(dest)], input=archive.stdout, check=True)
    probe = subprocess.run([sys.executable, "-c", "import cloth; print(cloth.__file__)"], cwd=dest,
                           env=_revision_env(dest), capture_output=True, text=True)
    if probe.returncode != 0 or not Path(probe.stdout.strip()).resolve().is_relative_to(dest.resolve()):
        raise RuntimeError(f"the exported tree of {commit[:12]} does not import its own cloth package "
                           f"({probe.stdout.strip() or probe.stderr.strip()[-300:]})")
    return dest


def _revision_env(src: Path) -> dict:
    path = [str(src), *filter(None, [os.environ.get("PYTHONPATH")])]
    return {**os.environ, "PYTHONPATH": os.pathsep.join(path)}


def bench_revision(src: Path, resolution: int, frames: int, warmup: int, solver: str, out: Path) -> dict:
    """One resolution timed by the benchmark of the tree at `src` (a subprocess); its steps.csv row."""
    before = set(out.iterdir()) if out.exists() else set()
    cmd = [sys.executable, "-m", "experiments.benchmark", "--resolutions", str(resolution), "--frames", str(frames),
           "--warmup", str(warmup), "--solver", solver, "--out", str(out)]
    done = subprocess.run(cmd, cwd=src, env=_revision_env(src), capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the benchmark of {src.name} failed (exit {done.returncode}): {done.stderr.strip()[-600:]}")
    (folder,) = set(out.iterdir()) - before
    return pd.read_csv(folder / "steps.csv").iloc[0].to_dict()


def bench_scene_revision(src: Path, args, out: Path) -> dict:
    """The scene timed by the benchmark of the tree at `src` (a subprocess, the same options); its scene.csv row."""
    before = set(out.iterdir()) if out.exists() else set()
    scene = str(Path(args.scene).expanduser().resolve()) if args.scene.endswith(".json") else args.scene
    cmd = [sys.executable, "-m", "experiments.benchmark", "--scene", scene, "--mode", args.mode, "--scale", args.scale,
           "--frames", str(args.frames), "--warmup", str(args.warmup), "--solver", args.solver,
           "--bending-hessian", args.bending_hessian, "--out", str(out), *args.overrides]
    done = subprocess.run(cmd, cwd=src, env=_revision_env(src), capture_output=True, text=True)
    if done.returncode != 0:
        raise RuntimeError(f"the scene benchmark of {src.name} failed (exit {done.returncode}; it needs the "
                           f"--scene option): {done.stderr.strip()[-600:]}")
    (folder,) = set(out.iterdir()) - before
    return pd.read_csv(folder / "scene.csv").iloc[0].to_dict()


def scene_against_row(rev: dict, head: dict) -> dict:
    """REV's microseconds per face per step over this tree's, per phase and collision part (>1: faster here)."""
    row = {"scene": head["scene"], "mode": head["mode"], "faces_rev": float(rev["faces_mean"]),
           "faces": float(head["faces_mean"]), "steps_per_frame_rev": float(rev["steps_per_frame"]),
           "steps_per_frame": float(head["steps_per_frame"]),
           "s_per_frame_rev": float(rev["s_per_frame"]), "s_per_frame": float(head["s_per_frame"])}
    for key in [k for k in head if k.endswith("us_per_face_step")]:  # every phase's and the whole step's
        if key in rev and float(head[key]) > 0:
            row[key[: -len("us_per_face_step")] + "speedup"] = float(rev[key]) / float(head[key])
    return row


def against_row(rev: dict, head: dict) -> dict:
    """REV's seconds per step over this tree's, per phase both record and overall (>1: this tree is faster)."""
    row = {"resolution": head["resolution"], "faces_rev": int(rev["faces"]), "faces": int(head["faces"]),
           "s_per_step_rev": float(rev["s_per_step"]), "s_per_step": float(head["s_per_step"]),
           "speedup": float(rev["s_per_step"]) / float(head["s_per_step"])}
    for p in PHASES:
        key = f"{p}_s_per_step"
        if key in rev and float(head[key]) > 0:
            row[f"{p}_speedup"] = float(rev[key]) / float(head[key])
    return row


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[32, 64, 128, 256],
                        help="cells per side: 2*r^2 faces (32 -> 2k, 64 -> 8k, 128 -> 32k, 256 -> 128k)")
    parser.add_argument("--frames", type=int, default=None, help="timed frames per run (6; --modes: 20)")
    parser.add_argument("--warmup", type=int, default=None, help="untimed frames before timing (12; --modes: 10)")
    parser.add_argument("--solver", choices=METHODS, default="auto",
                        help="linear solver (cloth.physics.linsolve); auto: cholesky where MKL loads, else pcg")
    parser.add_argument("--bending-hessian", choices=(*BENDING_HESSIANS, "both"), default=BENDING_HESSIAN_DEFAULT,
                        help="the bending term's Hessian (solver.bending_hessian; default: the solver's, "
                             f"{BENDING_HESSIAN_DEFAULT}); both: each resolution with each, and their ratio")
    parser.add_argument("--against", default=None, metavar="REV",
                        help="time commit REV's benchmark on the same sheets in the same run and print the speed-up")
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"))
    parser.add_argument("--report", type=Path, default=None, metavar="PAGE.md",
                        help="also write the tables as a Markdown page with the commit, machine and command "
                             "(docs/benchmark.md, docs/benchmark_modes.md)")
    parser.add_argument("--modes", action="store_true", help="the three modes at matched mean faces, per phase")
    parser.add_argument("--scene", default=None,
                        help="--modes: the scene (conf/scene/; default sheet_on_sphere); without --modes: time this "
                             "scene (conf/scene/ name or ARCSim .json) by phase")
    parser.add_argument("--mode", default="adaptive", choices=("nonadaptive", "adaptive", "viewdep"),
                        help="--scene: the mode (viewdep needs camera=... among the overrides)")
    parser.add_argument("--camera", default="sheet_half", help="--modes: mode=viewdep's camera (conf/camera/)")
    parser.add_argument("--scale", default="small", choices=("small", "paper"), help="--modes: the scene's preset")
    parser.add_argument("overrides", nargs="*", help="--modes, --scene: more config overrides (key=value)")
    args = parser.parse_args(argv)
    args.command = "python -m experiments.benchmark " + " ".join(sys.argv[1:] if argv is None else argv)
    if args.scene is not None and args.scene.endswith(".json") and (why := scene_error(args.scene)):
        parser.error(why)
    if args.scene is None and args.overrides and not args.modes:
        parser.error("overrides (key=value) go with --modes or --scene")
    solver = SolverOptions(method=args.solver)  # a method that cannot run here stops before any work
    against = None
    if args.against is not None:
        if args.modes or args.bending_hessian == "both":
            parser.error("--against: with the sheet or the scene benchmark (not --modes or --bending-hessian both)")
        try:
            against = resolve_revision(args.against)
        except ValueError as err:
            parser.error(str(err))
    hessians = BENDING_HESSIANS if args.bending_hessian == "both" else (args.bending_hessian,)
    if (args.modes or args.scene is not None) and args.bending_hessian == "both":
        parser.error("--bending-hessian both: not with --modes or --scene (run each, or give "
                     "solver.bending_hessian=... as an override)")
    if args.modes:
        args.scene = args.scene or "sheet_on_sphere"
        frames = 20 if args.frames is None else args.frames
        warmup = 10 if args.warmup is None else args.warmup
        for name, group in ((args.scene, "scene"), (args.camera, "camera")):
            if not (CONF / group / f"{name}.yaml").exists():
                parser.error(f"--{group} {name!r}: no conf/{group}/{name}.yaml")
    elif args.scene is not None:
        frames = 20 if args.frames is None else args.frames
        warmup = 5 if args.warmup is None else args.warmup
        if (why := scene_error(args.scene)) is not None:
            parser.error(why)
    else:
        frames = 6 if args.frames is None else args.frames
        warmup = 12 if args.warmup is None else args.warmup
    out_dir = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    if args.modes:
        df = bench_modes(args.scene, args.camera, frames, warmup,
                         [f"solver={args.solver}", f"solver.bending_hessian={args.bending_hessian}", *args.overrides],
                         args.scale)
        write_text_atomic(out_dir / "modes.csv", df.to_csv(index=False))
        phases = [f"{p}_us_per_face_step" for p in SIM_PHASES]
        print(df[["mode", "faces_mean", "s_per_frame", *phases, "us_per_face_step"]].to_string(
            index=False, float_format=lambda v: f"{v:.2f}"))
        ratio = df["us_per_face_step"].iloc[1] / df["us_per_face_step"].iloc[0]
        frame_ratio = df["s_per_frame"].iloc[1] / df["s_per_frame"].iloc[0]
        summary = {"scene": args.scene, "scale": args.scale, "resolution_factor": df.attrs["resolution_factor"],
                   "adaptive_over_fixed_frame_time": frame_ratio, "adaptive_over_fixed_per_face": ratio,
                   "rows": df.to_dict("records"), "manifest": environment_manifest(0)}
        write_json_atomic(out_dir / "summary.json", summary)
        print(f"adaptive / fixed at matched faces: {frame_ratio:.2f}x frame time ({ratio:.2f}x per face and step); "
              f"results in {out_dir}")
        if args.report is not None:
            table = df[["mode", "faces_mean", "s_per_frame", *phases, "us_per_face_step"]].rename(
                columns=lambda c: c.replace("_us_per_face_step", ""))
            write_report(args.report, "The three modes at matched faces",
                         f"`{args.scene}` (scale={args.scale}), microseconds per face per implicit step by phase "
                         f"over {frames} timed frames after {warmup}; the fixed mesh's resolution set so that its "
                         f"mean faces equal adaptive's, the view-dependent mode with camera `{args.camera}`. "
                         f"Adaptive over the fixed mesh: {frame_ratio:.2f}x frame time, {ratio:.2f}x per face and "
                         "step.", [("Per face per step (us)", table)], summary["manifest"], args.command)
        return
    if args.scene is not None:
        args.frames, args.warmup = frames, warmup
        rev_row = None
        if against is not None:  # REV first, then this tree: the same load for both
            with tempfile.TemporaryDirectory(prefix="cloth-against-") as tmp:
                src = export_revision(against, Path(tmp) / against[:12])
                rev_row = bench_scene_revision(src, args, Path(tmp) / "out")
        row = bench_scene(args.scene, args.mode, frames, warmup,
                          [f"solver={args.solver}", f"solver.bending_hessian={args.bending_hessian}",
                           *args.overrides], args.scale)
        write_text_atomic(out_dir / "scene.csv", pd.DataFrame([row]).to_csv(index=False))
        summary = {**row, "manifest": environment_manifest(0)}
        if rev_row is not None:
            compared = scene_against_row(rev_row, row)
            write_text_atomic(out_dir / "against.csv", pd.DataFrame([compared]).to_csv(index=False))
            summary["against"] = {"rev": args.against, "commit": against, **compared}
        write_json_atomic(out_dir / "summary.json", summary)
        print(f"{args.scene} ({args.mode}, scale={args.scale}): {row['faces_mean']:.0f} faces, "
              f"{row['steps_per_frame']:.1f} steps per frame (up to {row['steps_per_frame_max']}; the scene asks for "
              f"{row['scene_steps_per_frame']}), "
              f"{row['s_per_frame']:.3f} s per frame, collisions {100 * row['collision_share']:.0f} %")
        print("microseconds per face per step:")
        for p in SIM_PHASES:
            print(f"  {p:12s} {row[f'{p}_us_per_face_step']:8.2f}")
            if p == "collisions":
                for part in COLLISION_PARTS:
                    print(f"    {part:10s} {row[f'collisions_{part}_us_per_face_step']:8.2f}")
        print(f"  {'all':12s} {row['us_per_face_step']:8.2f}   results in {out_dir}")
        if rev_row is not None:
            parts = ", ".join(f"{k[:-len('_speedup')]} {v:.2f}x" for k, v in compared.items() if k.endswith("_speedup"))
            print(f"{args.against} / this tree, per face per step: {parts}")
        return
    args.frames, args.warmup = frames, warmup
    rows, compared = [], []
    with tempfile.TemporaryDirectory(prefix="cloth-against-") as tmp:
        src = export_revision(against, Path(tmp) / against[:12]) if against else None
        for r in args.resolutions:
            if src is not None:  # REV first, then this tree, resolution by resolution: the same load for both
                rev_row = bench_revision(src, r, frames, warmup, args.solver, Path(tmp) / "out")
            for hessian in hessians:
                row = bench(r, frames, warmup, SolverOptions(method=args.solver, bending_hessian=hessian))
                rows.append(row)
                _print_row(row, len(hessians) > 1)
            if len(hessians) > 1:
                p, g = rows[-2], rows[-1]
                print(f"    projected / gauss_newton: physics "
                      f"{p['physics_s_per_step'] / g['physics_s_per_step']:.2f}x, "
                      f"step {p['s_per_step'] / g['s_per_step']:.2f}x", flush=True)
            if src is not None:
                compared.append(against_row(rev_row, rows[-1]))
                c = compared[-1]
                parts = ", ".join(f"{p} {c[f'{p}_speedup']:.2f}x" for p in PHASES if f"{p}_speedup" in c)
                print(f"    {args.against} / this tree: step {c['speedup']:.2f}x ({parts})", flush=True)
        _finish_resolutions(rows, compared, args, against, hessians, solver, out_dir)


def _finish_resolutions(rows, compared, args, against, hessians, solver, out_dir) -> None:
    df = pd.DataFrame(rows)
    write_text_atomic(out_dir / "steps.csv", df.to_csv(index=False))
    fit = df[df["bending_hessian"] == hessians[0]]
    slope = float(np.polyfit(np.log(fit["faces"]), np.log(fit["s_per_step"]), 1)[0]) if len(fit) > 1 else float("nan")
    summary = {"growth_exponent": slope, "solver": resolve_method(solver.method), "rows": rows,
               "manifest": environment_manifest(0)}
    if against is not None:
        write_text_atomic(out_dir / "against.csv", pd.DataFrame(compared).to_csv(index=False))
        summary["against"] = {"rev": args.against, "commit": against, "rows": compared}
    write_json_atomic(out_dir / "summary.json", summary)
    print(f"time grows as faces^{slope:.2f} (1.00 = linear; {hessians[0]} Hessian); results in {out_dir}")
    if args.report is not None:
        what = (f"`sheet_on_sphere` at {', '.join(f'{r:,}' for r in df['faces'].unique())} faces ({args.frames} timed "
                f"frames after {args.warmup}), solver {summary['solver']}"
                + (f"; time grows as faces^{slope:.2f}." if np.isfinite(slope) else "."))
        if against is not None:
            what += (f" Against `{args.against}` ({against[:12]}): its own benchmark, run just before this tree's "
                     "at each size.")
        write_report(args.report, "Time per face per implicit step", what, sheet_tables(rows, compared),
                     summary["manifest"], args.command)


def sheet_tables(rows: list[dict], compared: list[dict]) -> list[tuple[str, pd.DataFrame]]:
    """The sheet benchmark's report tables: microseconds per face per step by phase, and with
    --against the previous commit's time over this tree's by phase."""
    per_face = pd.DataFrame([{"faces": r["faces"], "bending_hessian": r["bending_hessian"], "solver": r["solver"],
                              **{p: 1e6 * r[f"{p}_s_per_step"] / r["faces"] for p in SIM_PHASES},
                              "all": r["us_per_face_per_step"], "ms_per_step": 1e3 * r["s_per_step"]} for r in rows])
    tables = [("Per face per step (us)", per_face)]
    if compared:
        tables.append(("Previous commit's time over this tree's (above 1: this tree is faster)",
                       pd.DataFrame([{"faces": c["faces"], "step": c["speedup"],
                                      **{p: c[f"{p}_speedup"] for p in SIM_PHASES if f"{p}_speedup" in c}}
                                     for c in compared])))
    return tables


def write_report(path: Path, title: str, what: str, tables: list[tuple[str, pd.DataFrame]], manifest: dict,
                 command: str) -> None:
    """A benchmark's tables as a Markdown page, stamped with the commit, the machine and the command."""
    from experiments.analysis.tables import markdown  # noqa: PLC0415 - import cost: --report only

    dirty = " (with uncommitted changes)" if manifest.get("git_dirty") else ""
    lines = [f"# {title}", "",
             f"Measured at commit `{manifest.get('git_commit')}`{dirty}, {manifest.get('timestamp_utc')}, on "
             f"{manifest.get('cpu_model')}, {manifest.get('cpu_count')} cores, {manifest.get('numba_threads')} numba "
             f"thread(s): `{command}`. A benchmark on a "
             "shared machine: compare the ratios measured in one run, not times across pages.", "", what, ""]
    for heading, table in tables:
        lines += [f"## {heading}", "", markdown(table)]
    write_text_atomic(path, "\n".join(lines))
    print(f"report in {path}")


def _print_row(row: dict, name_hessian: bool) -> None:
    print(f"faces {row['faces']:6d}: {row['s_per_step'] * 1e3:8.1f} ms/step "
          f"({row['us_per_face_per_step']:.2f} us/face/step; physics {row['physics_s_per_step'] * 1e3:.1f}, "
          f"solve {row['solve_s_per_step'] * 1e3:.1f}, collisions {row['collisions_s_per_step'] * 1e3:.1f} ms; "
          f"{row['solver']}, CG {row['cg_iterations_per_step']:.0f} it, {row['solves_capped']} capped; "
          f"outside kernels+solver "
          f"{100 * row['share_outside_kernels_and_solver']:.1f}%)"
          + (f" [{row['bending_hessian']}]" if name_hessian else ""), flush=True)


if __name__ == "__main__":
    main()
