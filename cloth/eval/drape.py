"""The drape test's measures (Cusick drape tester, ISO 9073-9 / BS 5058).

A circular specimen of radius R is clamped flat on a smaller circular support of radius r and
drapes under gravity. Its measures, all from the cloth's positions:

* ``drape_coefficient`` DC = (A_shadow - A_support) / (A_specimen - A_support), A_shadow the area
  of the cloth's vertical projection (the shadow a lamp straight above casts: the union of the
  projected triangles, rasterised on SHADOW_CELLS x SHADOW_CELLS cells over the specimen's
  square), A_support = pi r^2, A_specimen the material area of the mesh (pi R^2 less what its
  polygonal border cuts off, so that a flat specimen gives 1 at any resolution). Towards 0 for a
  limp one.
* ``hem_radius_mean_m``, ``hem_radius_min_m``, ``hem_radius_max_m``: horizontal distance of the
  hem's nodes (material radius R) from the support's axis.
* ``overhang_elements``: elements across the overhang (R - r over the median material edge of the
  faces beyond the support): whether a mesh can show the folds at all.
* ``folds``: the number of folds around the hem: peaks of the hem's horizontal radius taken in
  order around the specimen (periodic), each standing out from its neighbours by at least
  FOLD_PROMINENCE of the radius' range and by FOLD_MIN_PROMINENCE_M (scipy.signal.find_peaks'
  prominence).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy.signal import find_peaks

SHADOW_CELLS = 600  # cells per side of the shadow's raster: 0.5 mm cells for a 30 cm specimen
# A fold is a peak of the hem's radius whose prominence is at least this fraction of the range
# of the radius around the hem (ripples of a node or two are not folds), and at least
# FOLD_MIN_PROMINENCE_M (a flat hem's round-off is not a fold).
FOLD_PROMINENCE = 0.1
FOLD_MIN_PROMINENCE_M = 1e-3


@njit(cache=True)
def _raster_union(xy, tris, lo, cell, n, covered):
    """Mark (into covered, n x n) the cells whose centres lie in any projected triangle."""
    for t in range(tris.shape[0]):
        a, b, c = xy[tris[t, 0]], xy[tris[t, 1]], xy[tris[t, 2]]
        det = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])
        if det == 0.0:
            continue
        i0 = max(int(np.floor((min(a[0], b[0], c[0]) - lo[0]) / cell - 0.5)), 0)
        i1 = min(int(np.ceil((max(a[0], b[0], c[0]) - lo[0]) / cell - 0.5)), n - 1)
        j0 = max(int(np.floor((min(a[1], b[1], c[1]) - lo[1]) / cell - 0.5)), 0)
        j1 = min(int(np.ceil((max(a[1], b[1], c[1]) - lo[1]) / cell - 0.5)), n - 1)
        for i in range(i0, i1 + 1):
            px = lo[0] + (i + 0.5) * cell
            for j in range(j0, j1 + 1):
                py = lo[1] + (j + 0.5) * cell
                w1 = ((px - a[0]) * (c[1] - a[1]) - (py - a[1]) * (c[0] - a[0])) / det
                w2 = ((b[0] - a[0]) * (py - a[1]) - (b[1] - a[1]) * (px - a[0])) / det
                if w1 >= 0.0 and w2 >= 0.0 and w1 + w2 <= 1.0:
                    covered[i, j] = True


def shadow_area(node_x: np.ndarray, face_nodes: np.ndarray, center, half_width: float,
                cells: int = SHADOW_CELLS) -> float:
    """Area (m^2) of the union of the triangles' vertical projections within the square of
    half-width `half_width` around `center` (x, y)."""
    xy = np.ascontiguousarray(np.asarray(node_x, dtype=np.float64)[:, :2])
    lo = np.asarray(center, dtype=np.float64)[:2] - half_width
    cell = 2.0 * half_width / cells
    covered = np.zeros((cells, cells), dtype=np.bool_)
    _raster_union(xy, np.ascontiguousarray(face_nodes, dtype=np.int64), lo, cell, cells, covered)
    return float(covered.sum()) * cell * cell


def drape_coefficient(a_shadow: float, a_support: float, a_specimen: float) -> float:
    """DC = (A_shadow - A_support) / (A_specimen - A_support), areas in m^2."""
    return float((a_shadow - a_support) / (a_specimen - a_support))


def count_folds(radius_around: np.ndarray) -> int:
    """Folds of a hem given its horizontal radius at nodes in order around it (periodic)."""
    r = np.asarray(radius_around, dtype=np.float64)
    if r.size < 3 or not np.ptp(r) > 0:
        return 0
    n = r.size
    prominence = max(FOLD_PROMINENCE * float(np.ptp(r)), FOLD_MIN_PROMINENCE_M)
    peaks, _ = find_peaks(np.concatenate([r, r, r]), prominence=prominence)
    return int(np.count_nonzero((peaks >= n) & (peaks < 2 * n)))


@dataclass
class DrapeProbe:
    """The drape measures of a specimen centred at `center` (its support's axis, x y), evaluated
    on a mesh whose material coordinates are centred on the specimen's centre (the scene's)."""

    center: tuple
    support_radius: float
    specimen_radius: float

    def overhang_elements(self, mesh) -> float:
        """Elements across the overhang (the specimen beyond its support): its width over the median
        material edge of the faces whose centroid lies beyond the support (NaN without any)."""
        u = mesh.vert_u[mesh.face_verts]  # (F, 3, 2)
        out = np.linalg.norm(u.mean(axis=1), axis=1) > self.support_radius
        if not out.any():
            return float("nan")
        edges = np.linalg.norm(u[out] - np.roll(u[out], -1, axis=1), axis=2)
        return float((self.specimen_radius - self.support_radius) / np.median(edges))

    def __call__(self, mesh) -> dict:
        c = np.asarray(self.center, dtype=np.float64)[:2]
        area = shadow_area(mesh.node_x, mesh.face_nodes, c, 1.05 * self.specimen_radius)
        r_mat = np.linalg.norm(mesh.vert_u, axis=1)
        hem = mesh.node_boundary[mesh.vert_node] & (r_mat > 0.5 * (self.support_radius + self.specimen_radius))
        verts = np.flatnonzero(hem)
        order = np.argsort(np.arctan2(mesh.vert_u[verts, 1], mesh.vert_u[verts, 0]))
        nodes = mesh.vert_node[verts[order]]
        radius = np.linalg.norm(mesh.node_x[nodes, :2] - c, axis=1)
        dc = drape_coefficient(area, np.pi * self.support_radius ** 2, float(mesh.face_area.sum()))
        return {"drape_coefficient": dc, "overhang_elements": self.overhang_elements(mesh),
                "hem_radius_mean_m": float(radius.mean()) if radius.size else float("nan"),
                "hem_radius_min_m": float(radius.min()) if radius.size else float("nan"),
                "hem_radius_max_m": float(radius.max()) if radius.size else float("nan"),
                "folds": count_folds(radius)}
