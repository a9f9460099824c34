"""Coarse-scale buckling compensation (Koh, Narain and O'Brien 2015, section 3.5, eqs 9-11).

Coarse faces cannot form the fine wrinkles that real cloth makes in place of in-plane
compression, so heavily coarsened cloth resists compression too much and balloons. For the
out-of-frustum faces, the compressive principal strains that the membrane sees are scaled down,

    E_i = 1/2 (F_i^T F_i - I)                                  (eq 9, cloth.physics.membrane.green_strain)
    lambda^_j = lambda_j if lambda_j >= 0, alpha_i lambda_j otherwise   (eq 10, :func:`filter_strain`)
    alpha_i = ((A_max - A_i) / (A_max - A_min))^k              (eq 11, :func:`compression_factor`)

with A the material-space face areas and A_max, A_min their extremes over the out-of-frustum
faces: the bigger a face, the more compressible. Every compensated face keeps alpha >= ALPHA_MIN
(`BucklingParams.alpha_min`; 0 gives the paper's eq 11 as written), and a compensated face squeezed
below COLLAPSE_AREA_RATIO of its area meets an area barrier (cloth.physics.membrane), so that none
collapses. The membrane kernel (cloth.physics.membrane) applies
eq 10 inside its energy, gradient and Hessian, per face, from the alpha this module computes.
This is a physical effect, independent of the view: mode=viewdep switches it on by default and
mode=adaptive can use it too (it needs a camera to know which faces are out of the frustum).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# Floor of alpha on the compensated faces. Eq 11 gives the largest out-of-frustum face alpha = 0:
# no resistance to compression at all. With the floor every face keeps alpha^2 = 1e-4 of its
# membrane's compression stiffness (eq 10 scales the strain, so the energy by alpha^2), and eq 11's
# ordering of the faces is kept above it. That alone does not stop a face from collapsing to a
# line (a hanging view-coarsened specimen did, and diverged): below a quarter of its rest area a
# compensated face meets the membrane's area barrier (cloth.physics.membrane.COLLAPSE_AREA_RATIO).
ALPHA_MIN = 0.01


class BucklingError(ValueError):
    """A buckling-compensation parameter that cannot work."""


def compression_factor(area, k: float) -> np.ndarray:
    """Eq 11, alpha_i = ((A_max - A_i) / (A_max - A_min))^k over the given (out-of-frustum) faces.

    `area` (F,) material-space areas, k >= 1. The smallest face keeps its full compression
    resistance (alpha = 1), the largest loses it (alpha = 0). Where all areas are equal there is
    no scale to compensate and alpha = 1.
    """
    area = np.asarray(area, dtype=np.float64)
    if not k >= 1:
        raise BucklingError(f"buckling k must be >= 1, got {k}")
    if area.size == 0:
        return np.ones(0)
    a_max, a_min = float(area.max()), float(area.min())
    if a_max - a_min <= 1e-12 * a_max:
        return np.ones_like(area)
    return ((a_max - area) / (a_max - a_min)) ** float(k)


def filter_strain(E, alpha) -> np.ndarray:
    """Eq 10 on symmetric 2x2 Green strains E (F, 2, 2): compressive principal strains times alpha (F,).

    E = Q diag(lambda_1, lambda_2) Q^T -> Q diag(lambda^_1, lambda^_2) Q^T with
    lambda^ = lambda where lambda >= 0 and alpha lambda where lambda < 0.
    """
    E = np.asarray(E, dtype=np.float64)
    if E.ndim == 2:  # one strain
        return filter_strain(E[None], np.reshape(alpha, -1)[:1])[0]
    alpha = np.broadcast_to(np.asarray(alpha, dtype=np.float64), E.shape[:1])
    lam, Q = np.linalg.eigh(E)
    lam = np.where(lam < 0, alpha[:, None] * lam, lam)
    return np.einsum("fik,fk,fjk->fij", Q, lam, Q)


@dataclass(frozen=True)
class BucklingParams:
    """Buckling compensation as a scene effect: alpha per out-of-frustum face, 1 elsewhere."""

    k: float = 10.0  # eq 11 exponent (the paper's k = 10)
    mode: str = "adaptive"  # adaptive: eq 11 | uniform: alpha = alpha_min on every out-of-frustum face (Fig. 6 middle)
    alpha_min: float = ALPHA_MIN  # floor of every compensated face's alpha, in [0, 1] (ALPHA_MIN)

    def __post_init__(self):
        if not self.k >= 1:
            raise BucklingError(f"buckling.k must be >= 1, got {self.k}")
        if not 0.0 <= self.alpha_min <= 1.0:
            raise BucklingError(f"buckling.alpha_min must be in [0, 1], got {self.alpha_min}")
        if self.mode not in ("adaptive", "uniform"):
            raise BucklingError(f"buckling.mode must be 'adaptive' or 'uniform', got {self.mode!r}")


def face_alpha(area: np.ndarray, out_of_frustum: np.ndarray, params: BucklingParams) -> np.ndarray:
    """(F,) compression factor of every face: eq 11 over the out-of-frustum ones, 1 on the others."""
    alpha = np.ones(area.shape[0])
    out = np.asarray(out_of_frustum, dtype=bool)
    if out.any():
        alpha[out] = 0.0 if params.mode == "uniform" else compression_factor(area[out], params.k)
        alpha[out] = np.maximum(alpha[out], params.alpha_min)
    return alpha


def compressive_energy(mesh, mu: float, lam: float, faces=None) -> float:
    """J: the St. Venant-Kirchhoff membrane energy of the compressive principal Green strains
    only, sum over `faces` (all if None) of A (mu (l1-^2 + l2-^2) + lam / 2 (l1- + l2-)^2), with
    l- = min(l, 0) the principal strains (eq 9) and A the material area: the in-plane compression
    a coarse mesh holds instead of buckling (what compensation removes out of the frustum)."""
    idx = np.arange(mesh.n_faces) if faces is None else np.asarray(faces)
    if idx.size == 0:
        return 0.0
    x = mesh.node_x[mesh.face_nodes[idx]]  # (F, 3, 3)
    Ds = np.stack([x[:, 1] - x[:, 0], x[:, 2] - x[:, 0]], axis=2)  # (F, 3, 2) world edges
    F = Ds @ mesh.face_Dm_inv[idx]
    E = 0.5 * (np.einsum("fki,fkj->fij", F, F) - np.eye(2))
    neg = np.minimum(np.linalg.eigvalsh(E), 0.0)
    density = mu * np.sum(neg ** 2, axis=1) + 0.5 * lam * np.sum(neg, axis=1) ** 2
    return float(np.sum(mesh.face_area[idx] * density))
