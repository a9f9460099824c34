"""The small symmetric eigensolver of the element Hessians' projection (cloth.physics.eigen)."""

import numpy as np
import pytest

from cloth.physics.eigen import symmetric_eig
from cloth.physics.membrane import project_psd

# Relative to the matrix's largest entry: a backward-stable decomposition of a 12x12 matrix is
# exact to a few hundred ulps; a wrong rotation or reflection shows at order 1.
ROUND_OFF = 1e-12


def _cases(rng):
    for n in (1, 2, 3, 9, 12):
        for _ in range(40):
            a = rng.normal(size=(n, n))
            yield a + a.T
            q, _ = np.linalg.qr(rng.normal(size=(n, n)))
            yield (q * rng.choice([-1.0, -1.0, 0.0, 2.0], size=n)) @ q.T  # repeated eigenvalues
        yield np.zeros((n, n))
        yield -np.eye(n)
        yield np.diag(np.arange(n, dtype=float) - n / 2)
        yield -np.ones((n, n))  # rank one
        yield 1e-200 * np.ones((n, n))
        yield 1e200 * np.eye(n) - 1e190 * np.ones((n, n))


def test_symmetric_eig_against_lapack():
    rng = np.random.default_rng(0)
    for a in _cases(rng):
        n = a.shape[0]
        w, v = np.empty(n), np.empty((n, n))
        symmetric_eig(a, w, v)
        scale = max(np.abs(a).max(), 1e-300)
        assert np.abs(a @ v - v * w).max() <= ROUND_OFF * scale
        assert np.abs(v.T @ v - np.eye(n)).max() <= ROUND_OFF
        assert np.abs(np.sort(w) - np.linalg.eigvalsh(a)).max() <= ROUND_OFF * scale


@pytest.mark.parametrize("absolute", [False, True])
def test_projection_is_the_eigenvalue_clamp(absolute):
    """V max(w, 0) V^T (or V |w| V^T), as LAPACK's decomposition gives it, and the input is kept
    where it is already positive semi-definite."""
    rng = np.random.default_rng(1)
    for a in _cases(rng):
        h = a.copy()
        project_psd(h, absolute)
        w, v = np.linalg.eigh(a)
        expected = (v * (np.abs(w) if absolute else np.maximum(w, 0.0))) @ v.T
        assert np.abs(h - expected).max() <= ROUND_OFF * max(np.abs(a).max(), 1e-300)
        assert np.array_equal(h, h.T)


def test_non_finite_matrix_is_refused():
    a = np.full((3, 3), np.nan)
    with pytest.raises(np.linalg.LinAlgError):
        symmetric_eig(a, np.empty(3), np.empty((3, 3)))


# A face's projection through its deformation gradient (6x6) against the 9x9 one: both are exact
# up to the eigensolver's round-off, summed over a few 9x9 products (measured: 2e-13).
FACE_PROJECTION_ROUND_OFF = 1e-11


def _compressed_faces(rng, n, tmp_path):
    """Exact StVK (plain or buckling-compensated) and measured-membrane Hessians of random faces,
    squeezed and sheared so that most are indefinite, with their g = [-1 -1; 1 0; 0 1] Dm^-1 rows
    and deformation gradients F."""
    from helpers import write_material

    from cloth.core.measured import load_arcsim_material
    from cloth.physics.measured_membrane import measured_element
    from cloth.physics.membrane import deformation_gradient, stvk_element

    samples = np.ascontiguousarray(load_arcsim_material(write_material(tmp_path / "knit.json")).stretching_samples)
    out = []
    while len(out) < n:
        u = rng.normal(size=(3, 2)) * 0.05
        Dm = np.stack([u[1] - u[0], u[2] - u[0]], 1)
        if abs(np.linalg.det(Dm)) < 1e-4:
            continue
        Dm_inv = np.linalg.inv(Dm)
        x = np.hstack([u, np.zeros((3, 1))]) * rng.uniform(0.5, 1.1) + rng.normal(size=(3, 3)) * 0.01
        area = 0.5 * abs(np.linalg.det(Dm))
        g = np.vstack([-Dm_inv.sum(axis=0), Dm_inv])
        F = deformation_gradient(x[0], x[1], x[2], Dm_inv)
        alpha = rng.choice([1.0, 0.3])  # 0.3: buckling compensation's filtered energy (eq 10)
        out.append((stvk_element(x[0], x[1], x[2], Dm_inv, area, 1e3, 2e3, False, alpha)[2], g, F))
        out.append((measured_element(x[0], x[1], x[2], Dm_inv, area, samples, alpha, False, np.empty(4))[2], g, F))
    return out


@pytest.mark.parametrize("absolute", [False, True])
def test_a_face_projected_through_its_deformation_gradient_equals_the_9x9_projection(absolute, tmp_path):
    """cloth.physics.membrane.project_psd_face: a face's Hessian is Q M Q^T with Q (9x6) orthonormal
    (the map to F, whitened by the rest shape), so projecting M (6x6) is projecting the Hessian."""
    from cloth.physics.membrane import project_psd_face

    rng = np.random.default_rng(1)
    indefinite = 0
    for H, g, _ in _compressed_faces(rng, 300, tmp_path):
        indefinite += bool(np.linalg.eigvalsh(H).min() < -1e-9 * np.abs(H).max())
        full, reduced = H.copy(), H.copy()
        project_psd(full, absolute)
        project_psd_face(reduced, g, absolute)
        assert np.abs(reduced - full).max() <= FACE_PROJECTION_ROUND_OFF * np.abs(H).max()
        assert np.array_equal(reduced, reduced.T)
    assert indefinite > 100  # the case exercises the projection


def _planar_basis(g, F):
    """(in-plane W (9, 4), out-of-plane W (9, 2)): project_psd_face_planar's whitened basis."""
    w, V = np.linalg.eigh(g.T @ g)
    h = g @ (V @ np.diag(w ** -0.5) @ V.T)
    n = np.cross(F[:, 0], F[:, 1])
    n /= np.linalg.norm(n)
    t1 = F[:, 0] / np.linalg.norm(F[:, 0])
    t2 = np.cross(n, t1)
    return (np.stack([np.kron(h[:, k], c) for c in (t1, t2) for k in (0, 1)], 1),
            np.stack([np.kron(h[:, k], n) for k in (0, 1)], 1))


# The in-plane / out-of-plane coupling of a face's Hessian, relative to its largest entry: zero
# in exact arithmetic for an energy of C = F^T F, a few ulps of the 9x9 products here.
PLANAR_COUPLING_ROUND_OFF = 1e-12


@pytest.mark.parametrize("absolute", [False, True])
def test_a_face_projected_by_its_plane_equals_the_9x9_projection(absolute, tmp_path):
    """cloth.physics.membrane.project_psd_face_planar: the Hessian of an energy of C = F^T F has
    no term coupling displacements along the face's normal to those in its plane, so projecting
    the out-of-plane 2x2 (closed form) and, when it is indefinite, the in-plane 4x4 is projecting
    the Hessian; both branches of the in-plane test are taken, and a face of no world area falls
    back to the 6x6 projection."""
    from cloth.physics.membrane import project_psd_face_planar

    rng = np.random.default_rng(2)
    in_plane_indefinite = out_of_plane_indefinite = 0
    faces = _compressed_faces(rng, 300, tmp_path)
    for H, g, F in faces:
        Win, Wn = _planar_basis(g, F)
        scale = np.abs(H).max()
        assert np.abs(Win.T @ H @ Wn).max() <= PLANAR_COUPLING_ROUND_OFF * scale
        in_plane_indefinite += bool(np.linalg.eigvalsh(Win.T @ H @ Win).min() < -1e-9 * scale)
        out_of_plane_indefinite += bool(np.linalg.eigvalsh(Wn.T @ H @ Wn).min() < -1e-9 * scale)
        full, planar = H.copy(), H.copy()
        project_psd(full, absolute)
        project_psd_face_planar(planar, g, F, absolute)
        assert np.abs(planar - full).max() <= FACE_PROJECTION_ROUND_OFF * scale
        assert np.array_equal(planar, planar.T)
    assert in_plane_indefinite > 50 and out_of_plane_indefinite > 100  # both blocks are exercised
    assert in_plane_indefinite < len(faces) - 50  # and so is the Cholesky test's passing branch
    H, g, F = faces[0]
    flat = F.copy()
    flat[:, 1] = 2.0 * flat[:, 0]  # collinear: no normal
    full, planar = H.copy(), H.copy()
    project_psd(full, absolute)
    project_psd_face_planar(planar, g, flat, absolute)
    assert np.abs(planar - full).max() <= FACE_PROJECTION_ROUND_OFF * np.abs(H).max()
