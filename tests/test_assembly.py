"""Sparse block assembly and the linear solvers, against dense brute force."""

import copy
import pickle

import numpy as np
import pytest
import scipy.sparse as sp

from cloth.core.mesh import grid_mesh
from cloth.physics.assembly import SparsityPattern, apply_dirichlet, bsr_matvec, scatter_blocks, scatter_forces
from cloth.physics.linsolve import (
    AUTO_CHOLESKY_UNKNOWNS,
    CNR_THREADS,
    SolverOptions,
    _threads,
    _upper_triangle,
    cholesky_available,
    limit_solver_threads,
    resolve_method,
    solve,
    solve_capped,
    solver_threads,
)

# Dense and sparse sums of the same O(1) products differ by round-off only.
ROUNDOFF = 1e-12
# PCG stops at a relative residual of 1e-10 here; the solution error is bounded by the
# condition number (~1e2 for these diagonally dominated random systems) times that.
PCG_TOL = 1e-10
SOLUTION_TOL = 1e-7


def _random_system(seed=0, nx=4, ny=3):
    rng = np.random.default_rng(seed)
    mesh = grid_mesh(1.0, 1.0, nx, ny)
    fams = {"faces": mesh.face_nodes, "hinges": mesh.edge_stencil()}
    pattern = SparsityPattern(mesh.n_nodes, fams)
    data = pattern.zeros()
    dense = np.zeros((3 * mesh.n_nodes, 3 * mesh.n_nodes))
    for name, en in fams.items():
        k = en.shape[1]
        hess = rng.standard_normal((en.shape[0], 3 * k, 3 * k))
        hess = hess @ hess.transpose(0, 2, 1)  # symmetric PSD element matrices
        scatter_blocks(data, pattern.slots[name], hess, 1.0)
        for e in range(en.shape[0]):
            idx = (3 * en[e][:, None] + np.arange(3)).reshape(-1)
            dense[np.ix_(idx, idx)] += hess[e]
    # make it definite like M + h^2 K
    for i in range(mesh.n_nodes):
        data[pattern.diag[i]] += 10.0 * np.eye(3)
    dense += 10.0 * np.eye(dense.shape[0])
    return mesh, pattern, data, dense, rng


def test_pattern_scatter_matches_dense_assembly():
    mesh, pattern, data, dense, _ = _random_system()
    assert np.allclose(pattern.to_scipy(data).toarray(), dense, rtol=0, atol=ROUNDOFF * np.abs(dense).max())
    # pattern rows are sorted and contain the diagonal
    for i in range(mesh.n_nodes):
        row = pattern.indices[pattern.indptr[i]:pattern.indptr[i + 1]]
        assert np.all(np.diff(row) > 0) and pattern.indices[pattern.diag[i]] == i


def test_pattern_holds_exactly_the_element_node_pairs_and_maps_each_to_its_slot():
    """The pattern's blocks are the sorted unique (row, col) pairs of the elements plus the
    diagonal (isolated nodes too), and every element's slot holds its own pair."""
    rng = np.random.default_rng(3)
    n = 40
    families = {"faces": rng.integers(0, n - 2, (60, 3)), "hinges": rng.integers(0, n - 2, (50, 4))}
    pattern = SparsityPattern(n, families)
    pairs = {(i, i) for i in range(n)}
    for en in families.values():
        pairs |= {(int(a), int(b)) for e in en for a in e for b in e}
    rows = np.repeat(np.arange(n), np.diff(pattern.indptr))
    assert sorted(pairs) == list(zip(rows.tolist(), pattern.indices.tolist(), strict=True))
    assert np.array_equal(pattern.indices[pattern.diag], np.arange(n))
    assert np.array_equal(rows[pattern.diag], np.arange(n))
    for name, en in families.items():
        slots = pattern.slots[name]
        k = en.shape[1]
        assert np.array_equal(rows[slots], np.repeat(en[:, :, None], k, axis=2))
        assert np.array_equal(pattern.indices[slots], np.repeat(en[:, None, :], k, axis=1))


def test_scatter_forces_and_matvec():
    mesh, pattern, data, dense, rng = _random_system(1)
    grad = rng.standard_normal((mesh.n_faces, 9))
    f = np.zeros((mesh.n_nodes, 3))
    scatter_forces(f, mesh.face_nodes, grad, -1.0)
    ref = np.zeros((mesh.n_nodes, 3))
    for e in range(mesh.n_faces):
        for a in range(3):
            ref[mesh.face_nodes[e, a]] -= grad[e, 3 * a:3 * a + 3]
    assert np.allclose(f, ref, atol=ROUNDOFF)
    x = rng.standard_normal((mesh.n_nodes, 3))
    y = np.empty_like(x)
    bsr_matvec(pattern.indptr, pattern.indices, data, x, y)
    assert np.allclose(y.reshape(-1), dense @ x.reshape(-1), atol=ROUNDOFF * np.abs(dense).max() * 10)


def test_pcg_and_direct_agree_with_dense_solve():
    mesh, pattern, data, dense, rng = _random_system(2)
    b = rng.standard_normal((mesh.n_nodes, 3))
    ref = np.linalg.solve(dense, b.reshape(-1)).reshape(-1, 3)
    x, it, res = solve(pattern, data, b, SolverOptions("pcg", PCG_TOL, 1000))
    assert res <= PCG_TOL and it > 0
    assert np.abs(x - ref).max() < SOLUTION_TOL
    x, _, res = solve(pattern, data, b, SolverOptions("direct"))
    assert np.abs(x - ref).max() < SOLUTION_TOL


def test_dirichlet_rows_give_prescribed_values_and_keep_symmetry():
    mesh, pattern, data, dense, rng = _random_system(3)
    b = rng.standard_normal((mesh.n_nodes, 3))
    fixed = np.zeros(mesh.n_nodes, bool)
    fixed[[0, 5]] = True
    value = rng.standard_normal((mesh.n_nodes, 3))
    apply_dirichlet(pattern.indptr, pattern.indices, data, b, fixed, value)
    A = pattern.to_scipy(data).toarray()
    assert np.allclose(A, A.T, atol=ROUNDOFF * np.abs(A).max())
    x, _, _ = solve(pattern, data, b, SolverOptions("pcg", PCG_TOL, 1000))
    assert np.allclose(x[fixed], value[fixed], atol=SOLUTION_TOL)
    # free unknowns solve the reduced system of the original matrix
    free = np.repeat(~fixed, 3)
    fixed3 = np.repeat(fixed, 3)
    _, _, _, dense0, rng0 = _random_system(3)  # the same system and right-hand side, unmodified
    b_orig = rng0.standard_normal((mesh.n_nodes, 3)).reshape(-1)
    rhs = b_orig[free] - dense0[np.ix_(free, fixed3)] @ value.reshape(-1)[fixed3]
    ref = np.linalg.solve(dense0[np.ix_(free, free)], rhs)
    assert np.abs(x.reshape(-1)[free] - ref).max() < SOLUTION_TOL


# --- the sparse Cholesky solver (cloth.physics.linsolve, method "cholesky") -------------------

needs_cholesky = pytest.mark.skipif(cholesky_available() is not None, reason=str(cholesky_available()))
# A factorization solves to round-off: 1e-10 relative residual leaves a margin of 1e2-1e3 over
# what PARDISO reaches on these systems (1e-13..1e-12).
DIRECT_RESIDUAL = 1e-10


def test_upper_triangle_map_gathers_the_scalar_upper_triangle():
    _, pattern, data, dense, _ = _random_system(4, nx=5, ny=4)
    indptr, indices, flat = _upper_triangle(pattern.indptr, pattern.indices)
    upper = sp.csr_matrix((data.reshape(-1)[flat], indices, indptr), shape=dense.shape)
    assert upper.has_sorted_indices
    assert np.allclose(upper.toarray(), np.triu(dense), rtol=0, atol=ROUNDOFF * np.abs(dense).max())
    # every entry of the upper triangle present, nothing of the lower one
    assert upper.nnz == sp.triu(pattern.to_scipy(np.ones_like(data))).nnz


@needs_cholesky
def test_cholesky_agrees_with_dense_solve_and_reuses_its_analysis():
    mesh, pattern, data, dense, rng = _random_system(5)
    b = rng.standard_normal((mesh.n_nodes, 3))
    x, it, res = solve(pattern, data, b, SolverOptions("cholesky"))
    assert it == 0 and res <= DIRECT_RESIDUAL
    assert np.abs(x - np.linalg.solve(dense, b.reshape(-1)).reshape(-1, 3)).max() < SOLUTION_TOL
    factor = pattern._cholesky
    # new values on the same pattern (the next step): the same factor object, a new solution
    data2 = data.copy()
    for i in range(mesh.n_nodes):
        data2[pattern.diag[i]] += 5.0 * np.eye(3)
    x2, _, res2 = solve(pattern, data2, b, SolverOptions("cholesky"))
    assert pattern._cholesky is factor and res2 <= DIRECT_RESIDUAL
    ref2 = np.linalg.solve(dense + 5.0 * np.eye(dense.shape[0]), b.reshape(-1)).reshape(-1, 3)
    assert np.abs(x2 - ref2).max() < SOLUTION_TOL


@needs_cholesky
def test_cholesky_on_an_indefinite_matrix_continues_as_pcg_and_is_counted_when_capped():
    mesh, pattern, data, _, rng = _random_system(6)
    data[pattern.diag[0]] -= 1e3 * np.eye(3)  # one strongly negative block: not positive definite
    b = rng.standard_normal((mesh.n_nodes, 3))
    options = SolverOptions("cholesky", tolerance=1e-12, max_iterations=2)
    x, it, res = solve(pattern, data, b, options)
    assert it == 2 and res > options.tolerance
    assert solve_capped(options, it, res)


def test_solver_method_is_checked_before_any_work():
    with pytest.raises(ValueError, match="solver.method must be one of auto, cholesky, pcg, direct"):
        SolverOptions("lu")
    factorizes = cholesky_available() is None
    assert resolve_method("auto", AUTO_CHOLESKY_UNKNOWNS) == ("cholesky" if factorizes else "pcg")
    assert resolve_method("auto", AUTO_CHOLESKY_UNKNOWNS - 3) == "pcg"  # a tiny system: CG is cheaper
    assert resolve_method("auto") == ("cholesky+pcg" if factorizes else "pcg")
    assert resolve_method("pcg", 10**6) == "pcg"


@needs_cholesky
def test_the_factorization_keeps_to_the_threads_it_is_given():
    """Applied at once when MKL is loaded; None lifts the limit; a share of none is refused."""
    try:
        assert limit_solver_threads(1) == 1 == solver_threads()
        assert limit_solver_threads(None) == min(CNR_THREADS, _threads["machine"])
        with pytest.raises(ValueError, match="at least one thread"):
            limit_solver_threads(0)
    finally:
        limit_solver_threads(None)


@needs_cholesky
def test_a_runs_share_of_the_cores_holds_the_factorization_to_it():
    """share_cores before the first solve (a run's order, in a fresh process): with as many runs
    as cores, each run's factorization takes one thread, not MKL's default of all of them."""
    import os
    import subprocess
    import sys

    script = ("import os\nfrom experiments.launch import share_cores\n"
              "from cloth.physics.linsolve import solver_threads\n"
              "print(share_cores(os.cpu_count()), solver_threads())")
    env = {**os.environ, "MKL_NUM_THREADS": str(max(2, os.cpu_count() or 1))}
    out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["1", "1"], out.stdout


@needs_cholesky
def test_a_copied_factor_analyses_again_and_solves_the_same():
    mesh, pattern, data, _, rng = _random_system(7)
    b = rng.standard_normal((mesh.n_nodes, 3))
    x, _, _ = solve(pattern, data, b, SolverOptions("cholesky"))
    twin = copy.deepcopy(pattern)  # a copied simulation carries its pattern
    assert twin._cholesky is not pattern._cholesky and not twin._cholesky._analysed
    x2, _, res = solve(twin, data, b, SolverOptions("cholesky"))
    assert res <= DIRECT_RESIDUAL and np.allclose(x2, x, rtol=0, atol=SOLUTION_TOL)
    assert pickle.loads(pickle.dumps(pattern))._cholesky.map.shape == pattern._cholesky.map.shape


_SOLVE_IN_A_PROCESS = """
import numpy as np
from cloth.core.material import Material
from cloth.physics.linsolve import SolverOptions
from cloth.scenes.registry import build_scene
from cloth.simulation import Simulation
cotton = Material("cotton", density=0.12, youngs_modulus=2.0e3, poisson_ratio=0.3, bending_stiffness=5e-6,
                  damping_mass=0.05, damping_stiffness=2e-3)
# 18k faces, 28k unknowns: large enough for PARDISO to split its work between threads, and
# 16 steps, so that an order of summation that follows the thread count shows (it did: the last
# hex digit of the checksum, without CNR)
sim = Simulation(build_scene("sheet_on_sphere", cotton, resolution=96), solver=SolverOptions("cholesky"))
for _ in range(2):
    sim.advance_frame()
print(float(np.abs(sim.mesh.node_x).sum()).hex())
"""


@pytest.mark.slow
@needs_cholesky
def test_the_factorization_gives_the_same_bits_on_one_and_two_threads():
    """MKL's conditional numerical reproducibility: a crowd's character (one thread in a worker)
    and the same character run alone (two) take the same steps."""
    import os
    import subprocess
    import sys

    script = _SOLVE_IN_A_PROCESS
    outputs = set()
    for threads in ("1", "2", "2"):
        env = {**os.environ, "MKL_NUM_THREADS": threads}
        out = subprocess.run([sys.executable, "-c", script], env=env, capture_output=True, text=True, check=True)
        outputs.add(out.stdout.strip())
    assert len(outputs) == 1, outputs
