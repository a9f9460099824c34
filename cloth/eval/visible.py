"""Statistics of the visible cloth that do not depend on the phase of its motion.

Two runs of a chaotic garment (the dancer's skirt) part after about a second, and then no
point-to-point error can say whether a coarse run looks like the fine one: it compares two
unrelated skirts. What a viewer sees can still be compared by its statistics over a shot: how
wrinkled the visible cloth is, how long its outline, how much of the screen it covers, how far
the hem flies out and how high. This module measures them on one frame (an image of
cloth.eval.screenspace and the state it was rendered from); experiments.accuracy averages them
per shot and scales each run's distance from the reference ensemble by the ensemble's own spread
(:func:`spread_distance`). Definitions (version :data:`DEFINITION_VERSION`), in pixels of the
camera's own image (an image rendered at ``resolution_scale`` s is converted):

* ``visible_area_px``: the pixels whose nearest surface is cloth, |R| / s^2.
* ``silhouette_length_px``: the length of the outline of R: the number of pixel sides between a
  cloth pixel and a pixel that is not cloth (inside the image; the image border is not an
  outline), times pi / 4 (a count of horizontal and vertical steps overestimates a curve of
  random direction by 4 / pi on average, Cauchy-Crofton), divided by s.
* ``wrinkle_energy_px2``: the mean over R of b(p)^2 f^2 / z(p)^2, with z the visible depth, f the
  focal length in pixels and b the band-pass of the depth inside the mask: the difference of two
  mask-normalised Gaussian blurs of z, at WRINKLE_SIGMA_PX = (1, 4) camera pixels (the band of
  wavelengths about 6-25 px; by Parseval, the spectral energy in that band under a smooth
  window). Depth relief turned sideways at its depth, squared: a flat or smoothly curved cloth
  gives about 0, folds and wrinkles of a few pixels give their squared relief.
* ``hem_radius_m``, ``hem_height_m`` (from the state, visible or not): the hem is the cloth's
  open boundary (edges of one face) away from its pinned nodes (the waistband), weighted by
  edge length; its radius is the mean horizontal distance of the hem from the vertical axis
  through the pinned nodes' centroid, its height the mean height of the hem above that
  centroid (negative: below). NaN without pinned nodes or without a hem (and for the merged
  image state of a crowd, which keeps no pins).
"""

from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter

DEFINITION_VERSION = "visible-v1"
STATISTICS = ("visible_area_px", "silhouette_length_px", "wrinkle_energy_px2", "hem_radius_m", "hem_height_m")
# The band of the wrinkle energy: Gaussian scales (camera pixels) of the fine and the coarse blur.
WRINKLE_SIGMA_PX = (1.0, 4.0)
# Mask-normalised blurs are taken where at least this fraction of the kernel's weight is cloth
# (elsewhere the blur of a pixel at the outline would be an extrapolation).
MIN_MASK_WEIGHT = 1e-3


def silhouette_length(mask: np.ndarray, scale: float = 1.0) -> float:
    """Outline length of a boolean mask in camera pixels (module docstring)."""
    m = np.asarray(mask, dtype=bool)
    sides = np.count_nonzero(m[1:, :] != m[:-1, :]) + np.count_nonzero(m[:, 1:] != m[:, :-1])
    return float(sides * math.pi / 4.0 / scale)


def _masked_blur(z: np.ndarray, mask: np.ndarray, sigma: float) -> np.ndarray:
    w = gaussian_filter(mask.astype(np.float64), sigma, mode="constant")
    v = gaussian_filter(np.where(mask, z, 0.0), sigma, mode="constant")
    return v / np.maximum(w, MIN_MASK_WEIGHT)


def wrinkle_energy(depth: np.ndarray, mask: np.ndarray, focal_px: float, scale: float = 1.0) -> float:
    """Mean squared band-pass depth relief over the mask, as camera pixels squared (module
    docstring); 0 for an empty mask."""
    m = np.asarray(mask, dtype=bool)
    if not m.any():
        return 0.0
    rows, cols = np.flatnonzero(m.any(axis=1)), np.flatnonzero(m.any(axis=0))
    pad = int(math.ceil(4 * WRINKLE_SIGMA_PX[1] * scale))  # the coarse kernel's reach: a crop changes nothing
    box = (slice(max(rows[0] - pad, 0), rows[-1] + pad + 1), slice(max(cols[0] - pad, 0), cols[-1] + pad + 1))
    m, z = m[box], np.where(m[box], depth[box], 0.0)
    fine, coarse = (_masked_blur(z, m, s * scale) for s in WRINKLE_SIGMA_PX)
    band = (fine - coarse)[m] * (focal_px / scale) / z[m]
    return float(np.mean(band * band))


def hem_statistics(state: dict) -> tuple[float, float]:
    """(hem_radius_m, hem_height_m) of a state with its pins (module docstring)."""
    pinned = state.get("node_pinned")
    if pinned is None or not np.any(pinned):
        return math.nan, math.nan
    x = np.asarray(state["node_x"], dtype=np.float64)
    faces = np.asarray(state["face_nodes"], dtype=np.int64)
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    uniq, count = np.unique(edges, axis=0, return_counts=True)
    boundary = uniq[count == 1]
    pinned = np.asarray(pinned, dtype=bool)
    hem = boundary[~pinned[boundary[:, 0]] & ~pinned[boundary[:, 1]]]
    if not len(hem):
        return math.nan, math.nan
    c = x[pinned].mean(axis=0)
    a, b = x[hem[:, 0]], x[hem[:, 1]]
    length = np.linalg.norm(b - a, axis=1)
    if not length.sum() > 0:
        return math.nan, math.nan
    mid = 0.5 * (a + b)
    radius = np.linalg.norm(mid[:, :2] - c[:2], axis=1)
    return float(np.average(radius, weights=length)), float(np.average(mid[:, 2] - c[2], weights=length))


def frame_statistics(image, state: dict) -> dict:
    """The statistics of STATISTICS of one frame: an image (cloth.eval.screenspace.ScreenImage)
    and the state it was rendered from."""
    cloth = image.cloth
    s = image.scale
    radius, height = hem_statistics(state)
    return {"visible_area_px": float(np.count_nonzero(cloth) / (s * s)),
            "silhouette_length_px": silhouette_length(cloth, s),
            "wrinkle_energy_px2": wrinkle_energy(image.depth, cloth, image.focal_px, s),
            "hem_radius_m": radius, "hem_height_m": height}


def spread_distance(run_value: float, member_values) -> tuple[float, float, float]:
    """(distance, members' mean, members' spread) of a run's statistic from a reference ensemble:
    |run - mean| / spread, with spread the members' sample standard deviation (NaN with fewer
    than two finite members or no spread): about 1 or below, the run is as far from the
    reference as one member is from another."""
    v = np.asarray(member_values, dtype=np.float64)
    v = v[np.isfinite(v)]
    if v.size == 0 or not math.isfinite(run_value):
        return math.nan, math.nan, math.nan
    mean = float(v.mean())
    spread = float(v.std(ddof=1)) if v.size > 1 else math.nan
    dist = abs(run_value - mean) / spread if spread > 0 else math.nan
    return dist, mean, spread
