"""Linear solvers for the implicit step.

- "cholesky": sparse Cholesky factorization (MKL PARDISO through pypardiso, nested-dissection
  ordering). Its symbolic analysis is done once per sparsity pattern, that is once per remesh,
  and every step refactors numerically only (a step's contacts change the matrix too much for
  an older factor to precondition it in a few iterations: measured, it never converged within
  four on the draped sheet). Its cost grows much more slowly with the mesh than block-Jacobi
  CG's, which needs about sqrt(faces) iterations (experiments.benchmark).
- "pcg": block-Jacobi preconditioned conjugate gradient (numba), capped at `max_iterations`.
- "direct": SuperLU through scipy, refactored from scratch every step (a reference).
- "auto" (the default): "cholesky" for systems of AUTO_CHOLESKY_UNKNOWNS unknowns or more where
  pypardiso loads (x86_64), otherwise "pcg". On a tiny system (a character out of view, tens of
  nodes) PARDISO's fixed cost per call is ten times what CG takes.

Every method answers to the same tolerance on the relative residual |b - A x| / |b|: a
factorization whose solution misses it (a matrix that is not positive definite, say) hands its
solution to PCG as a warm start, and the step's record counts the iterations that took.
"""

from __future__ import annotations

import copy
import functools
from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla
from numba import njit

from cloth.physics.assembly import SparsityPattern, bsr_matvec

METHODS = ("auto", "cholesky", "pcg", "direct")
# The bending Hessian the step's matrix holds (cloth.physics.bending): "projected", the exact one
# projected to positive semi-definite where it is not (a 9x9 eigen-decomposition per bent hinge);
# "gauss_newton", only its term w grad theta grad theta^T, PSD by construction and exact at the
# rest angle (ARCSim's). The forces are the same; only the step's matrix differs.
BENDING_HESSIANS = ("projected", "gauss_newton")
# The default, gauss_newton since the accuracy study of 50124b5 (solo_dancer, small, 40 paired
# windows, each mode restarted on its own mesh) found it not worse: adaptive -0.92 mm (90 %: -1.92
# to +0.15), view-dependent -2.56 mm (-9.81 to +3.48) against the projected Hessian, and the
# small stability suite passed 80 of 80 runs with it; physics 2.8-3.1x cheaper on the benchmark's
# sheet at 8k-32k faces (experiments.benchmark --bending-hessian both).
BENDING_HESSIAN_DEFAULT = "gauss_newton"
# The StVK membrane's Hessian: "projected", the exact one projected to positive semi-definite where
# the stress is not (per compressed face a closed-form 2x2 and, for about half of them, a 4x4
# eigen-decomposition, cloth.physics.membrane.project_psd_face_planar); "gauss_newton", the stress's positive
# part in the geometric term, PSD with no eigen-decomposition (what the pop filter uses). A face
# with buckling compensation is projected either way; ARCSim's measured membrane is projected.
# Not the default until the accuracy study and the stability suite have been run with it.
MEMBRANE_HESSIANS = ("projected", "gauss_newton")
# "auto" factorizes from this many unknowns (3 per node) up. Measured on the dancer's systems:
# 150-250 unknowns (out of view), PCG 0.13 ms per step against PARDISO's 1 ms; about 3,000
# (1.8k faces in view), PARDISO ahead; the sheet's 3,267, 17 ms against 3 ms. Measured again by
# experiments.solver_crossover (every solve of a run with both methods, 150 frames, scale=small,
# view-dependent; docs/solver_crossover.md): the factorization ahead from 600-900 unknowns up
# (1.1x there, 1.4-2.3x from 1,500), PCG ahead below; the total is flat from 600 to 2,000: in two
# runs of each, the best threshold was 600 and 1,200 on the solo dancer, 1,200 and 2,000 on karate,
# and this one's total within 1.5 % of the best's.
AUTO_CHOLESKY_UNKNOWNS = 1500
MKL_CBWR_AUTO = 2  # mkl_cbwr_set's mode: reproducible results on this machine's code path
CNR_THREADS = 2  # PARDISO's threads in CNR mode (iparm 34); MKL runs on at most this many
# The factorization's threads: "share", the run's share of the cores (limit_solver_threads; None:
# the whole machine); "machine", MKL's own count when it loaded (MKL_NUM_THREADS or the cores).
# Measured with one other run on the 2 cores (solo dancer, view-dependent, 30 frames,
# experiments.solver_crossover): PARDISO on 2 threads took 17.4 ms per solve of 2,000-3,000 unknowns
# against 12.0 ms on one, and the run's solves 4.56 s against 2.95 s: its threads wait on a core
# another run holds.
_threads: dict[str, int | None] = {"share": None, "machine": None}


def limit_solver_threads(threads: int | None) -> int:
    """Hold the factorization (MKL) to at most `threads` threads, the run's share of the cores
    (experiments.launch.share_cores gives numba the same; None: the whole machine again); returns
    the threads it will use (1 where the factorization cannot run). The results do not depend on
    it (CNR mode, _pardiso_template)."""
    if threads is not None and int(threads) < 1:
        raise ValueError(f"limit_solver_threads({threads}): at least one thread")
    _threads["share"] = None if threads is None else int(threads)
    template = _pardiso_template()  # loads MKL if need be
    if template is not None:
        _set_mkl_threads(template)
    return solver_threads()


def solver_threads() -> int:
    """The threads the factorization runs on (1 where it cannot run); loads MKL if need be."""
    template = _pardiso_template()
    return 1 if template is None else int(template.libmkl.MKL_Get_Max_Threads())


def _set_mkl_threads(template) -> None:
    if _threads["machine"] is None:  # MKL_Get_Max_Threads answers what was last set: read it first
        _threads["machine"] = max(1, int(template.libmkl.MKL_Get_Max_Threads()))
    share = _threads["share"]
    template.libmkl.MKL_Set_Num_Threads(min(CNR_THREADS, _threads["machine"], share or CNR_THREADS))


@functools.cache
def _pardiso_template():
    """A PARDISO handle whose library lookup (which runs the linker's tools: 0.25 s) the
    factorizations share; None where pypardiso or MKL does not load."""
    try:
        import pypardiso  # noqa: PLC0415 - optional dependency (MKL: x86_64 only)

        template = pypardiso.PyPardisoSolver(mtype=CholeskyFactor.SPD)
    except (ImportError, OSError):
        return None
    # Conditional numerical reproducibility: PARDISO's parallel factorization would sum in an order
    # that varies from run to run and with the thread count; a run must replay bit for bit, and a
    # crowd's character (in a worker process, on one thread) match the same character run alone
    # (tests/test_reproducibility.py, tests/test_assembly.py). With CNR on and iparm 34 fixed
    # (CholeskyFactor.IPARM), the results are the same on 1 and CNR_THREADS threads (tested), so
    # MKL is held to at most that many, and to the run's share of the cores (limit_solver_threads).
    template.libmkl.MKL_CBWR_Set(MKL_CBWR_AUTO)
    _set_mkl_threads(template)
    return template


def cholesky_available() -> str | None:
    """None when the Cholesky solver can run here, otherwise why it cannot."""
    if _pardiso_template() is None:
        return "pypardiso (MKL PARDISO) does not load here (it needs x86_64 and the mkl package)"
    return None


def resolve_method(method: str, unknowns: int | None = None) -> str:
    """The method that solves a system of `unknowns` unknowns: "auto" becomes "cholesky" where it
    can run and the system is large enough, else "pcg". Without `unknowns`, the method a run's
    record names ("auto" gives "cholesky+pcg" where the factorization can run)."""
    if method != "auto":
        return method
    if cholesky_available() is not None:
        return "pcg"
    if unknowns is None:
        return "cholesky+pcg"
    return "cholesky" if unknowns >= AUTO_CHOLESKY_UNKNOWNS else "pcg"


@dataclass(frozen=True)
class SolverOptions:
    method: str = "auto"  # one of METHODS (module docstring)
    tolerance: float = 1e-6  # relative residual |b - A x| / |b| every method must reach
    max_iterations: int = 1000  # PCG iteration cap; the record says when it is hit
    bending_hessian: str = BENDING_HESSIAN_DEFAULT  # one of BENDING_HESSIANS
    membrane_hessian: str = "projected"  # one of MEMBRANE_HESSIANS

    def __post_init__(self) -> None:
        if self.method not in METHODS:
            raise ValueError(f"solver.method must be one of {', '.join(METHODS)}, got {self.method!r}")
        if self.method == "cholesky" and (why := cholesky_available()) is not None:
            raise ValueError(f"solver.method=cholesky: {why}; use solver=pcg")
        if not self.tolerance > 0:
            raise ValueError(f"solver.tolerance must be > 0, got {self.tolerance}")
        if self.max_iterations < 1:
            raise ValueError(f"solver.max_iterations must be >= 1, got {self.max_iterations}")
        if self.bending_hessian not in BENDING_HESSIANS:
            raise ValueError(f"solver.bending_hessian must be one of {', '.join(BENDING_HESSIANS)}, "
                             f"got {self.bending_hessian!r}")
        if self.membrane_hessian not in MEMBRANE_HESSIANS:
            raise ValueError(f"solver.membrane_hessian must be one of {', '.join(MEMBRANE_HESSIANS)}, "
                             f"got {self.membrane_hessian!r}")


@njit(cache=True)
def _block_jacobi(indptr, diag, data):
    """Inverse of each 3x3 diagonal block (identity where singular)."""
    n = diag.shape[0]
    inv = np.empty((n, 3, 3))
    for i in range(n):
        a = data[diag[i]]
        det = (a[0, 0] * (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1])
               - a[0, 1] * (a[1, 0] * a[2, 2] - a[1, 2] * a[2, 0])
               + a[0, 2] * (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]))
        if det == 0.0:
            for r in range(3):
                for c in range(3):
                    inv[i, r, c] = 1.0 if r == c else 0.0
            continue
        inv[i, 0, 0] = (a[1, 1] * a[2, 2] - a[1, 2] * a[2, 1]) / det
        inv[i, 0, 1] = (a[0, 2] * a[2, 1] - a[0, 1] * a[2, 2]) / det
        inv[i, 0, 2] = (a[0, 1] * a[1, 2] - a[0, 2] * a[1, 1]) / det
        inv[i, 1, 0] = (a[1, 2] * a[2, 0] - a[1, 0] * a[2, 2]) / det
        inv[i, 1, 1] = (a[0, 0] * a[2, 2] - a[0, 2] * a[2, 0]) / det
        inv[i, 1, 2] = (a[0, 2] * a[1, 0] - a[0, 0] * a[1, 2]) / det
        inv[i, 2, 0] = (a[1, 0] * a[2, 1] - a[1, 1] * a[2, 0]) / det
        inv[i, 2, 1] = (a[0, 1] * a[2, 0] - a[0, 0] * a[2, 1]) / det
        inv[i, 2, 2] = (a[0, 0] * a[1, 1] - a[0, 1] * a[1, 0]) / det
    return inv


@njit(cache=True)
def _apply_precond(inv, r, z):
    for i in range(r.shape[0]):
        for a in range(3):
            z[i, a] = inv[i, a, 0] * r[i, 0] + inv[i, a, 1] * r[i, 1] + inv[i, a, 2] * r[i, 2]


@njit(cache=True)
def _dot(a, b):
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i, 0] * b[i, 0] + a[i, 1] * b[i, 1] + a[i, 2] * b[i, 2]
    return s


@njit(cache=True)
def pcg(indptr, indices, diag, data, b, x, tol, max_iter):
    """Solve A x = b (A symmetric positive definite, block-CSR) by preconditioned CG.

    `x` holds the initial guess and is overwritten with the solution. Returns
    (iterations, relative residual |b - A x| / |b|).
    """
    inv = _block_jacobi(indptr, diag, data)
    n = b.shape[0]
    r = np.empty((n, 3))
    bsr_matvec(indptr, indices, data, x, r)
    for i in range(n):
        for a in range(3):
            r[i, a] = b[i, a] - r[i, a]
    bnorm = np.sqrt(_dot(b, b))
    if bnorm == 0.0:
        for i in range(n):
            for a in range(3):
                x[i, a] = 0.0
        return 0, 0.0
    z = np.empty((n, 3))
    _apply_precond(inv, r, z)
    p = z.copy()
    q = np.empty((n, 3))
    rz = _dot(r, z)
    rnorm = np.sqrt(_dot(r, r))
    it = 0
    while it < max_iter and rnorm > tol * bnorm:
        bsr_matvec(indptr, indices, data, p, q)
        pq = _dot(p, q)
        if pq <= 0.0:  # loss of positive definiteness: stop with the best iterate so far
            break
        alpha = rz / pq
        for i in range(n):
            for a in range(3):
                x[i, a] += alpha * p[i, a]
                r[i, a] -= alpha * q[i, a]
        _apply_precond(inv, r, z)
        rz_new = _dot(r, z)
        beta = rz_new / rz
        rz = rz_new
        for i in range(n):
            for a in range(3):
                p[i, a] = z[i, a] + beta * p[i, a]
        rnorm = np.sqrt(_dot(r, r))
        it += 1
    return it, rnorm / bnorm


def solve_capped(options: SolverOptions, iterations: int, residual: float) -> bool:
    """True for a solve that stopped at its iteration cap with its residual still above the
    tolerance: an inexact step, which the frame's record counts (solves_capped). A factorization
    that misses the tolerance continues as PCG, so the test is the same for every method."""
    return (options.method != "direct" and iterations >= options.max_iterations
            and residual > options.tolerance)


@njit(cache=True)
def _upper_triangle(bindptr, bindices):
    """CSR pattern of the upper triangle of the scalar (3n x 3n) matrix of a block-CSR pattern
    whose block columns are sorted within each row, and for each of its entries the flat index
    into the block data (n_blocks * 9): returns (indptr, indices, map)."""
    n = bindptr.shape[0] - 1
    indptr = np.zeros(3 * n + 1, dtype=np.int32)
    for i in range(n):
        upper_blocks = 0
        for k in range(bindptr[i], bindptr[i + 1]):
            if bindices[k] > i:
                upper_blocks += 1
        for a in range(3):
            indptr[3 * i + a + 1] = indptr[3 * i + a] + (3 - a) + 3 * upper_blocks
    nnz = indptr[3 * n]
    indices = np.empty(nnz, dtype=np.int32)
    flat = np.empty(nnz, dtype=np.int64)
    for i in range(n):
        for a in range(3):
            pos = indptr[3 * i + a]
            for k in range(bindptr[i], bindptr[i + 1]):
                j = bindices[k]
                if j < i:
                    continue
                for b in range(a if j == i else 0, 3):
                    indices[pos] = 3 * j + b
                    flat[pos] = 9 * k + 3 * a + b
                    pos += 1
    return indptr, indices, flat


class CholeskyFactor:
    """Sparse Cholesky factorization of the block system of one sparsity pattern.

    The upper triangle of the scalar matrix, in CSR order, is gathered from the block data
    through an index map built once; PARDISO's analysis (ordering and symbolic factorization,
    phase 11) runs once, `factorize` refactors numerically (phase 22) and `substitute` solves
    with the factor (phase 33). A new pattern (after a remesh) gets a new factor.
    """

    SPD = 2  # PARDISO matrix type: real symmetric positive definite
    # iparm (1-based, as PARDISO's manual): our own settings (1), nested dissection (2: METIS),
    # no iterative refinement (8: the caller checks the residual, and CG finishes if need be: a
    # refinement step costs as much as the substitution), pivot perturbation 1e-8 (10: the
    # manual's value for symmetric matrices), the thread count of reproducible results (34).
    IPARM = {1: 1, 2: 2, 8: 0, 10: 8, 34: CNR_THREADS}

    def __init__(self, pattern: SparsityPattern):
        indptr, indices, self.map = _upper_triangle(pattern.indptr, pattern.indices)
        self.n = 3 * pattern.n_nodes
        self.upper = sp.csr_matrix((np.empty(self.map.shape[0]), indices, indptr), shape=(self.n, self.n))
        self._new_handle()

    def _new_handle(self) -> None:
        self._pardiso = copy.copy(_pardiso_template())  # the library, with a handle of its own:
        self._pardiso.pt = np.zeros_like(self._pardiso.pt)
        self._pardiso.iparm = np.zeros_like(self._pardiso.iparm)
        for k, v in self.IPARM.items():
            self._pardiso.iparm[k - 1] = v
        self._analysed = False

    def __getstate__(self) -> dict:
        """A copy (deepcopy, pickle: a checkpointed or copied simulation) keeps the pattern's
        gather map and analyses again on its first solve: PARDISO's handle is memory of this
        process."""
        return {"map": self.map, "upper": self.upper, "n": self.n}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._new_handle()

    def _phase(self, phase: int, rhs: np.ndarray) -> np.ndarray:
        self._pardiso.set_phase(phase)
        # pypardiso documents phases as its advanced usage; _call_pardiso runs the set phase
        return self._pardiso._call_pardiso(self.upper, rhs)

    def factorize(self, data: np.ndarray) -> None:
        """Factorize the block data `data` (n_blocks, 3, 3). Raises pypardiso's PyPardisoError
        when the factorization fails (a matrix that is not positive definite)."""
        np.take(data.reshape(-1), self.map, out=self.upper.data)
        rhs = np.zeros(self.n)
        if not self._analysed:
            self._phase(11, rhs)
            self._analysed = True
        self._phase(22, rhs)

    def substitute(self, b: np.ndarray) -> np.ndarray:
        """The factorized matrix's inverse applied to b (n, 3)."""
        return self._phase(33, np.asfortranarray(b.reshape(-1))).reshape(-1, 3)

    def solve(self, data: np.ndarray, b: np.ndarray) -> np.ndarray:
        """x with A x = b for the block data `data`, factorized afresh."""
        self.factorize(data)
        return self.substitute(b)

    def __del__(self):
        try:
            self._pardiso.free_memory(everything=True)
        except Exception:  # noqa: BLE001 - interpreter shutdown: nothing left to free
            pass


def _relative_residual(pattern: SparsityPattern, data: np.ndarray, b: np.ndarray, x: np.ndarray) -> float:
    r = np.empty_like(b)
    bsr_matvec(pattern.indptr, pattern.indices, data, x, r)
    bn = np.linalg.norm(b)
    return float(np.linalg.norm(b - r) / bn) if bn > 0 else 0.0


def _cholesky_of(pattern: SparsityPattern) -> CholeskyFactor:
    factor = getattr(pattern, "_cholesky", None)
    if factor is None:
        factor = CholeskyFactor(pattern)
        pattern._cholesky = factor  # lives and dies with the pattern, i.e. until the next remesh
    return factor


def solve(pattern: SparsityPattern, data: np.ndarray, b: np.ndarray, options: SolverOptions,
          x0: np.ndarray | None = None) -> tuple[np.ndarray, int, float]:
    """Solve the block system; returns (x (n,3), PCG iterations, relative residual).

    A direct method reports 0 iterations when it meets the tolerance by itself."""
    method = resolve_method(options.method, b.size)
    if method == "direct":
        A = pattern.to_scipy(data)
        x = spla.spsolve(A.tocsc(), b.reshape(-1)).reshape(-1, 3)
        return x, 0, _relative_residual(pattern, data, b, x)
    x = np.zeros_like(b) if x0 is None else x0.copy()
    if method == "cholesky":
        from pypardiso.pardiso_wrapper import PyPardisoError  # noqa: PLC0415 - optional dependency

        factor = _cholesky_of(pattern)
        try:
            xc = factor.solve(data, b)
        except PyPardisoError:
            xc = None  # not positive definite to PARDISO: PCG from the warm start
        if xc is not None and np.all(np.isfinite(xc)):
            res = _relative_residual(pattern, data, b, xc)
            if res <= options.tolerance:
                return xc, 0, res
            x = xc
    it, res = pcg(pattern.indptr, pattern.indices, pattern.diag, data, b, x,
                  options.tolerance, options.max_iterations)
    return x, int(it), float(res)
