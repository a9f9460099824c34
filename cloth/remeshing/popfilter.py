"""Pop filter: relax the spike of internal energy that a remesh introduces (Narain et al. 2012, sec 5).

Splitting and collapsing change the discretisation under a deformed cloth, so the new mesh's
internal forces differ from the old mesh's: left alone, that difference would show as a pop.
Right after a remesh we move the nodes a little, minimising

    P(x) = E_int(x) + sum_i f_i^0 . (x_i - x_i^0) + (mu / 2) |x - x^0|^2,

where E_int is the membrane and bending energy of the new mesh, x^0 the positions right after
the remesh and f^0 the internal forces of the *old* mesh carried onto the new nodes (per unit
mass, so a split node gets the mean acceleration of its edge). At a minimum,
f_int(x) = f^0 + mu (x - x^0): the new mesh pulls as the old one did, up to the rubber band mu
that keeps nodes near where they were. ARCSim carries the total acceleration of the last step
instead of the internal-force part; for cloth resting on an obstacle that total is zero while
its internal forces balance gravity and contact, and matching it would pull the cloth off.
Velocities are not changed. A few damped Newton iterations (backtracking line search) suffice.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cloth.core.mesh import Mesh
from cloth.physics.assembly import SparsityPattern, apply_dirichlet, scatter_blocks, scatter_forces
from cloth.physics.bending import GAUSS_NEWTON, bending_elements
from cloth.physics.forces import ForceTerm
from cloth.physics.linsolve import SolverOptions, solve

# Relative residual of the Newton systems: an inexact Newton step (PCG from zero) is a descent
# direction whatever its residual, the line search takes care of the rest, and |grad P| decides
# when to stop. At 1e-4 the filter ends where exact solves end (the same iterations, energies
# equal to 1e-6 on a draped sheet) in 70 % of the time: a factorization's analysis of each new
# region cost more than its Newton steps. 1e-2 was 7 % faster still, but on a material 100x
# stiffer, where the filter stops at its iteration cap, it left pops of 0.63 J (1e-4: 0.16 J,
# exact solves 0.13 J; experiments.stability's stiff_material).
NEWTON_SOLVE_TOLERANCE = 1e-4


# The farthest the filter may move a node, in lengths of the node's shortest edge: a relaxation that
# moves a node several edges past its neighbours is no longer a small correction but a pop of its
# own, and the filter then leaves the remesh's positions as they are. The throw it catches moved a
# node about 40 edges; a bound of 1 edge also caught big-step relaxations of layered sheets
# (experiments.stability's one_frame_step, seed 1), which then left a crossing.
POP_MAX_MOVE = 5.0


def _shortest_edges(mesh: Mesh, nodes: np.ndarray) -> np.ndarray:
    """(len(nodes),) the length of the shortest edge at each of `nodes`, in world space now."""
    fn, x = mesh.face_nodes, mesh.node_x
    shortest = np.full(mesh.n_nodes, np.inf)
    for a, b in ((0, 1), (1, 2), (2, 0)):
        length = np.linalg.norm(x[fn[:, a]] - x[fn[:, b]], axis=1)
        np.minimum.at(shortest, fn[:, a], length)
        np.minimum.at(shortest, fn[:, b], length)
    return shortest[nodes]


@dataclass(frozen=True)
class PopFilterParams:
    iterations: int = 5  # Newton iterations at most (ARCSim: 10)
    regularization: float = 1e3  # N/m, mu: stiffness of the rubber band to the post-remesh positions
    tolerance: float = 1e-3  # stop when |grad P| falls below this fraction of its first value

    def __post_init__(self):
        if self.iterations < 0:
            raise ValueError(f"pop_filter.iterations must be >= 0, got {self.iterations}")
        if not self.regularization > 0:
            raise ValueError(f"pop_filter.regularization must be > 0 N/m, got {self.regularization}")


def internal_forces(mesh: Mesh, terms: list[ForceTerm], pattern: SparsityPattern) -> np.ndarray:
    """Forces (n_nodes, 3) of the given (internal) terms on the whole mesh, without their stiffness."""
    force = np.zeros((mesh.n_nodes, 3))
    for term in terms:
        term.add_forces(mesh, 0.0, pattern, force)
    return force


class _Region:
    """The elements around the changed faces, renumbered compactly.

    Free nodes: the nodes of the changed faces and their one-ring (unpinned). Elements: every
    face and hinge with a free node (the energy of the others does not depend on the free
    nodes). Other nodes of those elements are held fixed.
    """

    def __init__(self, mesh: Mesh, changed_faces: np.ndarray, membrane, bending):
        fn = mesh.face_nodes
        seed = np.zeros(mesh.n_nodes, bool)
        seed[fn[changed_faces].reshape(-1)] = True
        ring = seed[fn].any(axis=1)
        free = np.zeros(mesh.n_nodes, bool)
        free[fn[ring].reshape(-1)] = True
        free &= ~mesh.node_pinned
        faces = np.flatnonzero(free[fn].any(axis=1))
        hinges = np.zeros(0, dtype=np.int64)
        if bending is not None:
            hinges = np.flatnonzero(free[bending.stencil].any(axis=1))
        used = np.zeros(mesh.n_nodes, bool)
        used[fn[faces].reshape(-1)] = True
        if bending is not None:
            used[bending.stencil[hinges].reshape(-1)] = True
        self.nodes = np.flatnonzero(used)
        local = np.full(mesh.n_nodes, -1, dtype=np.int64)
        local[self.nodes] = np.arange(self.nodes.size)
        self.free = free[self.nodes]
        self.membrane, self.bending = membrane, bending
        self.face_nodes = np.ascontiguousarray(local[fn[faces]], dtype=np.int32)
        self.Dm_inv = np.ascontiguousarray(mesh.face_Dm_inv[faces])
        self.area = np.ascontiguousarray(mesh.face_area[faces])
        self.alpha = np.ascontiguousarray(membrane.alpha[faces]) if membrane is not None else np.ones(faces.size)
        fam = {"faces": self.face_nodes}
        if bending is not None:
            self.stencil = np.ascontiguousarray(local[bending.stencil[hinges]], dtype=np.int32)
            self.rest_theta = np.ascontiguousarray(bending.rest_theta[hinges])
            self.weight = np.ascontiguousarray(bending.weight[hinges])
            fam["hinges"] = self.stencil
        self.pattern = SparsityPattern(self.nodes.size, fam)

    def evaluate(self, x: np.ndarray):
        """(energy, force (n, 3), stiffness blocks) of the region's elements at local positions x."""
        n = x.shape[0]
        force = np.zeros((n, 3))
        K = self.pattern.zeros()
        energy = 0.0
        F = self.face_nodes.shape[0]
        if self.membrane is not None and F:
            e, g, H = np.empty(F), np.empty((F, 9)), np.empty((F, 9, 9))
            # Gauss-Newton membrane Hessian (the stress's positive part): PSD without a 9x9 eigensolve
            # per compressed face (the projection was half of the filter's time on a draped sheet)
            self.membrane.elements(x, self.face_nodes, self.Dm_inv, self.area, self.alpha, e, g, H, GAUSS_NEWTON)
            scatter_forces(force, self.face_nodes, g, -1.0)
            scatter_blocks(K, self.pattern.slots["faces"], H, 1.0)
            energy += float(e.sum())
        if self.bending is not None and self.stencil.shape[0]:
            E = self.stencil.shape[0]
            e, g, H = np.empty(E), np.empty((E, 12)), np.empty((E, 12, 12))
            # Gauss-Newton bending Hessian: positive semi-definite without an eigensolve per hinge
            # (the projection was 60% of a remesh at 12k faces); the line search keeps descent
            bending_elements(x, self.stencil, self.rest_theta, self.weight, GAUSS_NEWTON, e, g, H)
            scatter_forces(force, self.stencil, g, -1.0)
            scatter_blocks(K, self.pattern.slots["hinges"], H, 1.0)
            energy += float(e.sum())
        return energy, force, K


def pop_filter(mesh: Mesh, terms: list[ForceTerm], changed_faces: np.ndarray, target_force: np.ndarray,
               params: PopFilterParams, solver: SolverOptions) -> dict:
    """Minimise P(x) in place on `mesh.node_x`, over the nodes around `changed_faces`.

    `terms` are the simulation's force terms (the Membrane and Bending ones are used, already
    rebuilt for `mesh`); `changed_faces` (F,) bool marks faces the remesh created or changed.
    Newton's systems are solved by PCG to NEWTON_SOLVE_TOLERANCE, whatever `solver`'s method
    (its iteration cap applies).
    Returns {'energy_before_j', 'energy_after_j', 'iterations', 'free_nodes', 'reverted'}: the
    internal energy of the region's elements right after the remesh and after the filter, and 1
    when the filter's minimum lay more than POP_MAX_MOVE shortest edges from a node's position,
    so that the nodes were left where the remesh put them.
    """
    membrane = next((t for t in terms if t.name == "membrane"), None)
    bending = next((t for t in terms if t.name == "bending"), None)
    out = {"energy_before_j": 0.0, "energy_after_j": 0.0, "iterations": 0, "free_nodes": 0, "reverted": 0}
    if not np.any(changed_faces) or (membrane is None and bending is None):
        return out
    region = _Region(mesh, changed_faces, membrane, bending)
    free = region.free
    out["free_nodes"] = int(free.sum())
    x0 = mesh.node_x[region.nodes].copy()
    f0 = target_force[region.nodes]
    mu = params.regularization
    x = x0.copy()

    def evaluate(x):
        e_int, force, K = region.evaluate(x)
        d = x - x0
        P = e_int + float(np.sum(f0[free] * d[free])) + 0.5 * mu * float(np.sum(d * d))
        grad = -force + f0 + mu * d
        grad[~free] = 0.0
        return P, e_int, grad, K

    P, e_int, grad, K = evaluate(x)
    out["energy_before_j"] = out["energy_after_j"] = e_int
    g0 = float(np.linalg.norm(grad))
    if g0 == 0.0:
        return out
    pattern = region.pattern
    newton = SolverOptions(method="pcg", tolerance=NEWTON_SOLVE_TOLERANCE, max_iterations=solver.max_iterations)
    for it in range(params.iterations):
        H = K.copy()
        H[pattern.diag] += mu * np.eye(3)
        rhs = -grad
        apply_dirichlet(pattern.indptr, pattern.indices, H, rhs, ~free, np.zeros_like(rhs))
        dx, _, _ = solve(pattern, H, rhs, newton)
        slope = float(np.sum(grad * dx))
        step = 1.0
        for _ in range(20):  # backtracking (Armijo)
            x_new = x + step * dx
            P_new, e_new, grad_new, K_new = evaluate(x_new)
            if P_new <= P + 1e-4 * step * slope:
                break
            step *= 0.5
        else:
            break
        x, P, e_int, grad, K = x_new, P_new, e_new, grad_new, K_new
        out["iterations"] = it + 1
        if float(np.linalg.norm(grad)) < params.tolerance * g0:
            break
    move = np.linalg.norm(x - x0, axis=1)[free] / _shortest_edges(mesh, region.nodes)[free]
    if move.size and float(move.max()) > POP_MAX_MOVE:
        # The filter moves nodes "a little"; its linear term pulls them along the old mesh's
        # forces, held back only by the rubber band mu: where the old mesh was far from rest
        # (cloth caught between body parts) those forces reach 1e4 N and the minimum of P lies
        # metres away (seen: karate, view-dependent, seed 2, frame 90: 104 J became 1,369 J, a
        # node thrown 2 m, the next step at 363 m/s). The positions the remesh left are kept.
        out["reverted"] = 1
        return out
    mesh.node_x[region.nodes[free]] = x[free]
    out["energy_after_j"] = e_int
    return out
