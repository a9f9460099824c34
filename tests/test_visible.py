"""Statistics of visible cloth (cloth.eval.visible) on constructed cases with known answers."""

import math

import numpy as np
import pytest

from cloth.eval.screenspace import CLOTH, EMPTY, ScreenImage
from cloth.eval.visible import (
    WRINKLE_SIGMA_PX,
    frame_statistics,
    hem_statistics,
    silhouette_length,
    spread_distance,
    wrinkle_energy,
)

# A digitised circle's outline, counted in pixel sides times pi/4, is its perimeter to within
# about 1 % at radii of tens of pixels (the Crofton estimate's error for a smooth closed curve).
OUTLINE_REL = 0.02
# The mask-normalised band-pass of a sinusoid, against its analytic gain: the image border (where
# the normalised blur sees a half kernel) is a few percent of a 600 px image.
BAND_REL = 0.1


def _disk(n: int, r: float, scale: float = 1.0) -> np.ndarray:
    yy, xx = np.mgrid[0:n, 0:n] + 0.5
    c = n / 2
    return (xx - c) ** 2 + (yy - c) ** 2 <= (r * scale) ** 2


def test_silhouette_length_of_a_disk_is_its_perimeter_at_any_render_scale():
    for scale in (1.0, 2.0):
        n = int(200 * scale)
        length = silhouette_length(_disk(n, 60.0, scale), scale)
        assert length == pytest.approx(2 * math.pi * 60.0, rel=OUTLINE_REL)
    assert silhouette_length(np.zeros((50, 50), bool)) == 0.0
    assert silhouette_length(np.ones((50, 50), bool)) == 0.0  # the image border is not an outline


def _band_gain(wavelength_px: float) -> float:
    k = 2 * math.pi / wavelength_px
    s1, s2 = WRINKLE_SIGMA_PX
    return math.exp(-0.5 * (s1 * k) ** 2) - math.exp(-0.5 * (s2 * k) ** 2)


def test_wrinkle_energy_of_flat_and_corrugated_depth():
    n, z0, f = 600, 2.0, 500.0
    mask = np.ones((n, n), bool)
    assert wrinkle_energy(np.full((n, n), z0), mask, f) == pytest.approx(0.0, abs=1e-20)
    x = np.arange(n) + 0.5
    amp = 0.002  # m of relief: 0.5 px at 2 m with f = 500 px
    for wavelength in (10.0, 16.0):
        depth = z0 + amp * np.sin(2 * math.pi * x / wavelength)[None, :] * np.ones((n, 1))
        expected = 0.5 * (_band_gain(wavelength) * amp * f / z0) ** 2
        assert wrinkle_energy(depth, mask, f) == pytest.approx(expected, rel=BAND_REL)
    # a long swell of the same relief is out of the band
    swell = z0 + amp * np.sin(2 * math.pi * x / 300.0)[None, :] * np.ones((n, 1))
    ripple = z0 + amp * np.sin(2 * math.pi * x / 12.0)[None, :] * np.ones((n, 1))
    assert wrinkle_energy(swell, mask, f) < 0.05 * wrinkle_energy(ripple, mask, f)
    # the outline of a flat disk is not a wrinkle: the blur is normalised by the mask
    disk = _disk(n, 150.0)
    assert wrinkle_energy(np.where(disk, z0, np.inf), disk, f) == pytest.approx(0.0, abs=1e-20)
    assert wrinkle_energy(np.full((n, n), np.inf), np.zeros((n, n), bool), f) == 0.0


def _cone_skirt(n_around=64, rings=6, r0=0.15, r1=0.6, drop=0.3, shift=(0.0, 0.0, 1.0)):
    """A conical skirt: ring 0 (the waistband, pinned) at radius r0, the hem ring at r1 and drop
    metres below it; centred at `shift`."""
    theta = 2 * math.pi * np.arange(n_around) / n_around
    x = []
    for j in range(rings + 1):
        t = j / rings
        r, z = r0 + t * (r1 - r0), -drop * t
        x.append(np.stack([r * np.cos(theta), r * np.sin(theta), np.full(n_around, z)], axis=1))
    x = np.concatenate(x) + np.asarray(shift)
    faces = []
    for j in range(rings):
        for i in range(n_around):
            a, b = j * n_around + i, j * n_around + (i + 1) % n_around
            c, d = a + n_around, b + n_around
            faces += [(a, b, d), (a, d, c)]
    pinned = np.zeros(len(x), bool)
    pinned[:n_around] = True
    return {"node_x": x, "face_nodes": np.array(faces), "node_pinned": pinned}


def test_hem_radius_and_height_of_a_cone():
    n = 64
    state = _cone_skirt(n_around=n, shift=(0.3, -0.2, 1.1))
    radius, height = hem_statistics(state)
    # the hem's edge midpoints lie at r1 cos(pi / n) (a regular polygon's apothem)
    assert radius == pytest.approx(0.6 * math.cos(math.pi / n), rel=1e-12)
    assert height == pytest.approx(-0.3, rel=1e-12)
    unpinned = {**state, "node_pinned": np.zeros_like(state["node_pinned"])}
    assert all(math.isnan(v) for v in hem_statistics(unpinned))
    assert all(math.isnan(v) for v in hem_statistics({k: v for k, v in state.items() if k != "node_pinned"}))


def test_frame_statistics_of_an_image_and_state():
    n = 120
    disk = _disk(n, 30.0)
    img = ScreenImage(np.where(disk, 2.0, np.inf), np.where(disk, CLOTH, EMPTY).astype(np.int8),
                      np.where(disk, 0, -1).astype(np.int32), 300.0, 1.0)
    s = frame_statistics(img, _cone_skirt())
    assert s["visible_area_px"] == disk.sum()
    assert s["silhouette_length_px"] == pytest.approx(2 * math.pi * 30.0, rel=OUTLINE_REL)
    assert s["wrinkle_energy_px2"] == pytest.approx(0.0, abs=1e-20)
    assert s["hem_height_m"] == pytest.approx(-0.3)


def test_spread_distance_by_hand():
    dist, mean, spread = spread_distance(4.0, [1.0, 2.0, 3.0])
    assert (dist, mean, spread) == pytest.approx((2.0, 2.0, 1.0))
    assert spread_distance(2.0, [1.0, 2.0, 3.0])[0] == 0.0
    assert math.isnan(spread_distance(4.0, [2.0])[0])  # one member: no spread
    assert math.isnan(spread_distance(4.0, [2.0, 2.0])[0])  # no spread
    assert math.isnan(spread_distance(math.nan, [1.0, 2.0])[0])
    assert spread_distance(5.0, [1.0, math.nan, 3.0])[0] == pytest.approx(3.0 / math.sqrt(2.0))
