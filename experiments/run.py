"""Run one simulation from the Hydra config: ``python -m experiments.run scene=flag frames=30``.

Everything is built and checked from the config before any work starts; a config error stops
with one message naming the key. The run folder (Hydra's output dir) receives the resolved
config, manifest.json, frames.parquet, summary.json, recording.rrd and optional OBJ frames.
"""

from __future__ import annotations

import sys
from pathlib import Path

import hydra
from omegaconf import DictConfig, OmegaConf

from experiments.build import ConfigError, build_simulation


def run_from_config(cfg: DictConfig, out_dir: Path) -> dict:
    """Validate, build, run and record; returns the summary (raises ConfigError first if bad)."""
    from cloth.io.manifest import environment_manifest, write_json_atomic
    from cloth.runner import run

    sim, n_frames = build_simulation(cfg)  # every config check happens here, before any output
    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    write_json_atomic(out_dir / "manifest.json", environment_manifest(int(cfg.seed)))
    recorder = None
    if cfg.output.rerun:
        from cloth.io.recorder import RerunRecorder
        recorder = RerunRecorder(out_dir / "recording.rrd", app_id=f"cloth_{cfg.scene.name}")
    return run(sim, n_frames, out_dir, recorder=recorder, obj_every=int(cfg.output.obj_every),
               progress=bool(cfg.output.progress))


@hydra.main(config_path="../conf", config_name="config", version_base="1.3")
def main(cfg: DictConfig) -> None:
    from cloth.simulation import SimulationDiverged

    out_dir = Path(hydra.core.hydra_config.HydraConfig.get().runtime.output_dir)
    try:
        summary = run_from_config(cfg, out_dir)
    except ConfigError as exc:
        print(f"config error: {exc}", file=sys.stderr)
        sys.exit(2)
    except SimulationDiverged as exc:
        print(f"run stopped: {exc}\nframes written so far are in {out_dir}", file=sys.stderr)
        sys.exit(3)
    print(f"run folder: {out_dir}")
    print(f"  frames: {summary['frames_completed']}  faces: {summary.get('faces_mean', 0):.0f}  "
          f"mean time per frame: {summary.get('wall_s_mean', 0):.3f} s")
    if cfg.output.rerun:
        print(f"  recording: {out_dir / 'recording.rrd'}  (view with: rerun {out_dir / 'recording.rrd'})")


if __name__ == "__main__":
    main()
