"""Checks and the seeded jitter shared by the scene builders (cloth.scenes.sheets, dancers)."""

from __future__ import annotations

import numpy as np

from cloth.core.scene import SceneError


def _check_resolution(name: str, resolution: int) -> None:
    if int(resolution) < 1:
        raise SceneError(f"scene {name!r}: resolution must be >= 1 cell, got {resolution}")


def _check_size(name: str, **sizes: float) -> None:
    for key, value in sizes.items():
        if not value > 0:
            raise SceneError(f"scene {name!r}: {key} must be > 0 m, got {value}")


def _jitter(mesh, amplitude: float, seed: int) -> None:
    """Tiny seeded out-of-plane noise that breaks the perfect symmetry of a grid."""
    if amplitude > 0:
        rng = np.random.default_rng(seed)
        mesh.node_x[:, 2] += amplitude * rng.standard_normal(mesh.n_nodes)
