"""Write an example OBJ sequence, a swinging icosphere (50 frames of 0.04 s), for the mesh_obstacle
scene: ``python -m experiments.obstacle_obj [DIR]`` (default results/obstacle_obj).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from cloth.io.obj import write_obj_sequence
from cloth.scenes.bodies import moving_sphere_keyframes


def main(argv: list[str]) -> int:
    out = Path(argv[0] if argv else "results/obstacle_obj")
    times = np.arange(50) * 0.04
    centers = np.column_stack([0.15 * np.sin(np.pi * times), np.zeros_like(times), 0.25 + 0.0 * times])
    X, F = moving_sphere_keyframes(0.25, 2, centers)
    written = write_obj_sequence(out, X, F)
    print(f"wrote {len(written)} frames: {out}/frame_*.obj")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
