"""Helpers shared by the test modules (plain functions and constants; the fixtures built on them
are in tests/conftest.py). A test module imports what it needs from here (`from helpers import
...`: pytest puts tests/ on sys.path) and never from another test module.

- configs: `compose_config` (conf/ with overrides), `config_choices` (the files of a group);
- simulations: `build_sim` (from overrides), `simulation_in_mode` (a Python-built Scene in one
  of the three modes), `mode_overrides`, `MODES`;
- runs: `run_config` (a run folder from overrides), `read_frames`, `run_module` (python -m in a
  new process), `write_run` (a run folder made by hand: what aggregation reads), `write_study_runs`
  (such folders for every study);
- checks: `after_every_step` (a check after each step of a simulation), `count_crossings`,
  `material_edge_lengths`;
- small scenes: `COTTON`, `two_sheets`;
- measured materials: `MEASURED_JSON`, `write_material` (a small material file in ARCSim's format).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pandas as pd
import yaml
from hydra import compose, initialize_config_dir
from omegaconf import DictConfig

from cloth.collision.untangle import find_intersections
from cloth.core.material import Material
from cloth.core.mesh import grid_mesh, merge_meshes
from cloth.simulation import Simulation
from experiments.build import (
    build_buckling,
    build_camera,
    build_remesher,
    build_simulation,
    command_line_wins,
    plain_experiment,
)
from experiments.launch import run_from_config

ROOT = Path(__file__).resolve().parents[1]  # the repository
CONF = str(ROOT / "conf")  # Hydra's config directory (an absolute path, as initialize_config_dir wants)

# conf/material/cotton.yaml, for the scenes the tests build in Python (tests/test_physics.py,
# tests/test_meshobstacle.py; other tests use variants of their own, e.g. without damping).
COTTON = Material("cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3,
                  bending_stiffness=5e-6, damping_mass=0.05, damping_stiffness=2e-3)

# The three modes of the frame loop (conf/mode/); every physical check that applies runs in each.
MODES = ("nonadaptive", "adaptive", "viewdep")
# mode=viewdep needs a camera: by default the static camera above the +x half of sheet_on_sphere
# (conf/camera/sheet_half.yaml), which the view-dependent tests use.
VIEWDEP_CAMERA = "sheet_half"
# What a test run writes besides its records and states: no Rerun recording, no progress bar.
QUIET = ("output.rerun=false", "output.progress=false")


# ---- configs -------------------------------------------------------------------------------

def config_choices(group: str) -> list[str]:
    """The options of a config group: the names of conf/<group>/*.yaml, sorted, without the
    shared bases (a leading underscore: conf/experiment/_base.yaml is not a study)."""
    return sorted(p.stem for p in (ROOT / "conf" / group).glob("*.yaml") if not p.stem.startswith("_"))


def compose_config(*overrides: str, return_hydra_config: bool = False) -> DictConfig:
    """conf/config.yaml composed with `overrides` (Hydra's command-line syntax), the command line
    winning over the scale preset as in experiments.run (experiments.build.command_line_wins)."""
    overrides = plain_experiment(overrides)  # +experiment=NAME as the command line takes it (experiments.run.cli)
    with initialize_config_dir(config_dir=CONF, version_base="1.3"):
        cfg = compose(config_name="config", overrides=list(overrides), return_hydra_config=return_hydra_config)
    return command_line_wins(cfg, overrides)


def mode_overrides(mode: str, camera: str = VIEWDEP_CAMERA) -> tuple[str, ...]:
    """The overrides that select `mode`, with `camera` for mode=viewdep (which needs one)."""
    return (f"mode={mode}", f"camera={camera}") if mode == "viewdep" else (f"mode={mode}",)


# ---- simulations ---------------------------------------------------------------------------

def build_sim(*overrides: str) -> Simulation:
    """The Simulation of the config composed with `overrides` (experiments.build.build_simulation)."""
    return build_simulation(compose_config(*overrides))[0]


def simulation_in_mode(scene, mode: str, camera: str = VIEWDEP_CAMERA, **kwargs) -> Simulation:
    """A Simulation of a Python-built `scene` in `mode`: conf/mode/<mode>.yaml's remesher and, for
    mode=viewdep, conf/camera/<camera>.yaml as the scene's camera and the mode's buckling
    compensation, set up as experiments.build does; `kwargs` go to Simulation (solver, ...).
    mode=nonadaptive is `Simulation(scene, **kwargs)`."""
    if mode == "nonadaptive":
        return Simulation(scene, **kwargs)
    cfg = compose_config(*mode_overrides(mode, camera))
    path = build_camera(cfg) if mode == "viewdep" else None
    if path is not None:
        scene.camera = path
    remesher = build_remesher(cfg.mode, {}, path, scene.frame_time)
    return Simulation(scene, remesher=remesher, buckling=build_buckling(cfg.mode, path), **kwargs)


def after_every_step(sim: Simulation, check, before=None) -> None:
    """Make `sim` call `check(sim)` at the end of each of its steps (before the frame's record),
    and `before(sim)`, if given, at the start of each."""
    step = sim.step

    def checked(timings, stats):
        if before is not None:
            before(sim)
        step(timings, stats)
        check(sim)

    sim.step = checked


def material_edge_lengths(mesh) -> np.ndarray:
    """(3 F,) lengths in material space (m) of the faces' edges: every face's first edges, then
    their second, then their third (edge k joins corners k and k + 1)."""
    fv, u = mesh.face_verts, mesh.vert_u
    return np.concatenate([np.linalg.norm(u[fv[:, (k + 1) % 3]] - u[fv[:, k]], axis=1) for k in range(3)])


def count_crossings(mesh) -> int:
    """Crossing face pairs of the cloth with itself (cloth.collision.untangle.find_intersections)."""
    return len(find_intersections(mesh.face_nodes, mesh.node_x)[0])


# ---- small scenes --------------------------------------------------------------------------

def two_sheets(n=6, gap=0.02, size=0.3, shift=(0.013, 0.007), density=COTTON.density):
    """A sheet of n x n cells, `size` m across, and a smaller one (0.8 x) `gap` m above it,
    shifted by 0.03 m + `shift` off its corner (no edge of one above an edge of the other).
    Returns (merged mesh with rest data, number of nodes of the lower sheet)."""
    lower = grid_mesh(size, size, n, n, origin=(0.0, 0.0, 0.0))
    upper = grid_mesh(size * 0.8, size * 0.8, n, n, origin=(0.03 + shift[0], 0.03 + shift[1], gap))
    mesh = merge_meshes([lower, upper])
    mesh.update_rest_data(density)
    return mesh, lower.n_nodes


# ---- runs ----------------------------------------------------------------------------------

def run_config(out: Path, *overrides: str) -> dict:
    """Run the config composed with `overrides` into the folder `out` (experiments.run); its summary."""
    return run_from_config(compose_config(*overrides), out)


def read_frames(run_dir: Path) -> pd.DataFrame:
    """The per-frame records of a run folder (frames.parquet)."""
    return pd.read_parquet(Path(run_dir) / "frames.parquet")


# write_run's frames: their frame time (s), and the I/O added to each frame's simulation time to
# give its wall_s (Table 1 must not count it).
FRAME_TIME_S = 0.04
IO_S = 0.5


def write_run(folder: Path, scene: str, mode: str, faces, verts, sim_s, *, study="table1", variant=None,
              scale="small", status="completed", frames_requested=None, timestamp="2025-01-01T00:00:00+00:00",
              view=None, buckling=None, accuracy=None, accuracy_frames=None, extra_frames=None, camera_cuts=None,
              sync=None,
              summary_extra=None, scene_view=None, seed=0, manifest=None) -> Path:
    """A run folder as experiments.run writes it (only what aggregation reads)."""
    folder.mkdir(parents=True)
    n = len(sim_s)
    mode_cfg = {"name": mode}
    if mode == "viewdep":
        mode_cfg["view"] = {"nu_out": 0.01, "margin": 0.4, "anticipation_frames": 5, "anticipation": True,
                            **(view or {})}
        mode_cfg["buckling"] = {"k": 10, "mode": "adaptive"} if buckling is None else (buckling or None)
    scene_cfg = {"name": scene, "params": {"frame_time": FRAME_TIME_S}, **({"view": scene_view} if scene_view else {})}
    cfg = {"scene": scene_cfg, "mode": mode_cfg, "scale": scale,
           "frames": frames_requested or n, "seed": seed, "study": study, "variant": variant, "reference": False}
    if camera_cuts:
        cfg["camera"] = {"type": "cuts", "shots": [{"start": 0.0}] + [{"start": c} for c in camera_cuts]}
    (folder / "config.yaml").write_text(yaml.safe_dump(cfg))
    frames = pd.DataFrame({"frame": np.arange(1, n + 1), "sim_time_s": np.arange(1, n + 1) * FRAME_TIME_S,
                           "faces": faces, "verts": verts, "sim_s": sim_s,
                           "wall_s": np.asarray(sim_s, float) + IO_S, **(extra_frames or {})})
    frames.to_parquet(folder / "frames.parquet", index=False)
    summary = {"status": status, "message": "", "frames_requested": frames_requested or n, "frames_completed": n,
               **(summary_extra or {})}
    (folder / "summary.json").write_text(json.dumps(summary))
    (folder / "manifest.json").write_text(json.dumps({"timestamp_utc": timestamp, **(manifest or {})}))
    if accuracy is not None:
        (folder / "accuracy.json").write_text(json.dumps(accuracy))
    if accuracy_frames is not None:
        pd.DataFrame(accuracy_frames).to_parquet(folder / "accuracy.parquet", index=False)
    if sync is not None:
        (folder / "sync.json").write_text(json.dumps(sync))
    return folder



def module_env(**extra: str) -> dict:
    """This process's environment with the repository on PYTHONPATH and `extra` added: the
    environment of `run_module`, or of a process started otherwise (e.g. with Popen)."""
    return dict(os.environ, PYTHONPATH=str(ROOT), **extra)


def run_module(*args: str, env: dict | None = None, timeout: float = 600) -> subprocess.CompletedProcess:
    """`python -m <args>` in a new process in the repository (environment: `module_env`, with `env`
    added; a value None removes that variable), its output captured as text."""
    full_env = module_env()
    for key, value in (env or {}).items():
        if value is None:
            full_env.pop(key, None)
        else:
            full_env[key] = value
    return subprocess.run([sys.executable, "-m", *args], cwd=ROOT, env=full_env, capture_output=True, text=True,
                          timeout=timeout)


# ---- elements ----------------------------------------------------------------------------

def random_rest_triangle(seed: int):
    """(u (3, 2) counter-clockwise material corners, Dm^-1 (2, 2), area) of a seeded random triangle."""
    r = np.random.default_rng(seed)
    u = r.standard_normal((3, 2))
    d1, d2 = u[1] - u[0], u[2] - u[0]
    if d1[0] * d2[1] - d1[1] * d2[0] < 0:
        u = u[[0, 2, 1]]
    Dm = np.column_stack([u[1] - u[0], u[2] - u[0]])
    return u, np.linalg.inv(Dm), 0.5 * np.linalg.det(Dm)


# ---- measured materials ------------------------------------------------------------------

# A made-up material in ARCSim's format (no ARCSim file is in the repository: it is not ours to
# copy). Stretching rows: zero strain, then a stretch of 1 + 1/6 at 0, 22.5, 45, 67.5, 90 degrees
# (N/m, before ARCSim doubles them); row 0's k1 < 0 is clamped to 0 by the table. Bending rows:
# edges at 0, 45, 90 degrees; columns: curvatures 0, 10, 20, 30, 40 1/m (N m).
MEASURED_JSON = {
    "density": 0.2,
    "stretching": [[20.0, -5.0, 40.0, 30.0],
                   [60.0, 40.0, 200.0, 20.0],
                   [55.0, 45.0, 180.0, 25.0],
                   [50.0, 50.0, 160.0, 30.0],
                   [45.0, 45.0, 150.0, 25.0],
                   [40.0, 40.0, 140.0, 20.0]],
    "bending": [[2.0e-5, 3.0e-5, 3.5e-5, 4.0e-5, 4.2e-5],
                [1.5e-5, 2.0e-5, 2.5e-5, 2.8e-5, 3.0e-5],
                [1.0e-5, 1.2e-5, 1.6e-5, 2.0e-5, 2.2e-5]],
}


def write_material(path: Path, data: dict | None = None, text: str | None = None) -> Path:
    """Write a material file (`data` as JSON, MEASURED_JSON by default, or `text` as it is) to `path`."""
    path = Path(path)
    path.write_text(text if text is not None else json.dumps(MEASURED_JSON if data is None else data))
    return path


def write_study_runs(root: Path) -> None:
    """Run folders of every study under `root`, small and made up (write_run): Table 1, a nu_out
    sweep with accuracy, both ablations (what the figures, the docs pages and the report read)."""
    s = "solo_dancer"
    write_run(root / "t1" / "0_na", s, "nonadaptive", [90] * 4, [50] * 4, [2.0] * 4, variant="nonadaptive")
    write_run(root / "t1" / "1_ad", s, "adaptive", [40, 50, 60, 50], [25, 30, 35, 30], [1.0] * 4, variant="adaptive")
    write_run(root / "t1" / "2_vd", s, "viewdep", [10, 20, 30, 20], [8, 13, 18, 13], [0.5] * 4, variant="viewdep")
    sw = root / "sweep"
    write_run(sw / "0_ad", s, "adaptive", [50] * 4, [30] * 4, [1.0] * 4, study="sweep_nu_out", variant="adaptive",
              accuracy={"error_px_mean": 0.5, "offscreen_distance_m_mean": 0.0})
    for i, (nu, wall, err) in enumerate(((0.001, 0.25, 4.0), (0.01, 0.5, 2.0), (0.1, 0.8, 3.0))):
        write_run(sw / f"{i + 1}_vd", s, "viewdep", [20] * 4, [12] * 4, [wall] * 4, study="sweep_nu_out",
                  variant=f"nu_out={nu}", view={"nu_out": nu}, accuracy={"error_px_mean": err})
    ab = root / "buckling"
    for i, (bk, off) in enumerate((({}, 0.05), ({"k": 10, "mode": "uniform"}, 0.01), ({"k": 10, "mode": "adaptive"},
                                                                                         0.02))):
        write_run(ab / f"{i}_vd", s, "viewdep", [20] * 4, [12] * 4, [0.5] * 4, study="ablation_buckling",
                  buckling=bk, accuracy={"error_px_mean": 3.0 + i, "offscreen_distance_m_mean": off},
                  accuracy_frames={"frame": [1, 2, 3, 4], "error_px": [1.0] * 4, "offscreen_distance_m": [off] * 4})
