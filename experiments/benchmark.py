"""Benchmark: time per implicit step of `sheet_on_sphere` at about 2k, 8k, 32k and 128k faces.

    python -m experiments.benchmark [--resolutions 32 64 128 256] [--frames 6] [--warmup 12]
                                    [--solver auto|cholesky|pcg|direct] [--out DIR]

A benchmark, not a test: it prints ratios measured in one run and writes
`<out>/<timestamp>/steps.csv` (default out: results/benchmark) (one row per resolution: seconds per step by phase,
microseconds per face per step, the share of step time outside compiled kernels and the
linear solver) and `summary.json` (the growth exponent of time with faces, from a log-log fit,
and the solver that ran).

Time inside compiled kernels is measured by wrapping every numba dispatcher that the Python
layer calls outside the linear solve (the wrappers add about a microsecond per call, a few dozen
calls per step); the solve's own time is its phase.
"""

from __future__ import annotations

import argparse
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
from cloth.core.records import PHASES
from cloth.io.manifest import environment_manifest, write_json_atomic, write_text_atomic
from cloth.physics.linsolve import METHODS, SolverOptions, resolve_method
from cloth.scenes.registry import build_scene
from cloth.simulation import Simulation

COTTON = dict(name="cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3,
              bending_stiffness=5e-6, damping_mass=0.05, damping_stiffness=2e-3)
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
    scene = build_scene("sheet_on_sphere", Material(**COTTON), resolution=resolution)
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
           "solver": resolve_method(solver.method, 3 * sim.mesh.n_nodes), "steps": steps, "s_per_step": wall / steps}
    for p in PHASES:
        out[f"{p}_s_per_step"] = df[f"time_{p}_s"].sum() / steps
    out["us_per_face_per_step"] = 1e6 * wall / steps / sim.mesh.n_faces
    out["cg_iterations_per_step"] = df["solver_iterations"].sum() / steps
    out["solves_capped"] = int(df["solves_capped"].sum())
    out["kernel_s_per_step"] = clock.seconds / steps  # compiled kernels outside the solve
    solve_s = df["time_solve_s"].sum()
    out["share_outside_kernels_and_solver"] = max(0.0, 1.0 - (clock.seconds + solve_s) / wall)
    return out


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--resolutions", type=int, nargs="+", default=[32, 64, 128, 256],
                        help="cells per side: 2*r^2 faces (32 -> 2k, 64 -> 8k, 128 -> 32k, 256 -> 128k)")
    parser.add_argument("--frames", type=int, default=6, help="timed frames per resolution")
    parser.add_argument("--warmup", type=int, default=12, help="untimed frames before timing")
    parser.add_argument("--solver", choices=METHODS, default="auto",
                        help="linear solver (cloth.physics.linsolve); auto: cholesky where MKL loads, else pcg")
    parser.add_argument("--out", type=Path, default=Path("results/benchmark"))
    args = parser.parse_args(argv)
    solver = SolverOptions(method=args.solver)  # a method that cannot run here stops before any work
    out_dir = args.out / datetime.now().strftime("%Y-%m-%d_%H-%M-%S")
    out_dir.mkdir(parents=True, exist_ok=True)
    rows = []
    for r in args.resolutions:
        row = bench(r, args.frames, args.warmup, solver)
        rows.append(row)
        print(f"faces {row['faces']:6d}: {row['s_per_step'] * 1e3:8.1f} ms/step "
              f"({row['us_per_face_per_step']:.2f} us/face/step; physics {row['physics_s_per_step'] * 1e3:.1f}, "
              f"solve {row['solve_s_per_step'] * 1e3:.1f}, collisions {row['collisions_s_per_step'] * 1e3:.1f} ms; "
              f"{row['solver']}, CG {row['cg_iterations_per_step']:.0f} it, {row['solves_capped']} capped; "
              f"outside kernels+solver "
              f"{100 * row['share_outside_kernels_and_solver']:.1f}%)", flush=True)
    df = pd.DataFrame(rows)
    write_text_atomic(out_dir / "steps.csv", df.to_csv(index=False))
    slope = float(np.polyfit(np.log(df["faces"]), np.log(df["s_per_step"]), 1)[0]) if len(df) > 1 else float("nan")
    summary = {"growth_exponent": slope, "solver": resolve_method(solver.method), "rows": rows,
               "manifest": environment_manifest(0)}
    write_json_atomic(out_dir / "summary.json", summary)
    print(f"time grows as faces^{slope:.2f} (1.00 = linear); results in {out_dir}")


if __name__ == "__main__":
    main()
