"""Force terms: one class per physical effect, each adding energy, forces and Jacobians.

A step is assembled once from the list of terms the scene asks for (see
:func:`cloth.stages.build_force_terms`), so a term that is not listed is never called.

Every term implements

* ``families``: names of the element families whose node stencils it couples ("faces",
  "hinges"; see :func:`element_families`), for the sparsity pattern; may be empty;
* ``rebuild(mesh, pattern)``: per-topology and per-rest-state precomputation;
* ``accumulate(mesh, t, acc)``: add its energy, force, stiffness ``K = -df/dx`` and velocity
  Jacobian ``D = -df/dv`` to the accumulator ``acc`` (accumulates into ``acc``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numba import njit

from cloth.core.mesh import Mesh
from cloth.physics.assembly import SparsityPattern, scatter_blocks, scatter_forces
from cloth.physics.bending import GAUSS_NEWTON, bending_elements, hinge_weight
from cloth.physics.dde import hinge_rest_data, hinge_stiffness
from cloth.physics.measured_membrane import measured_membrane_elements
from cloth.physics.membrane import membrane_elements


@dataclass
class ForceAccumulator:
    """Per-step sums of all force terms (world space)."""

    force: np.ndarray  # (n_nodes, 3) float64, N
    K: np.ndarray  # (n_blocks, 3, 3) float64, N/m: stiffness -df/dx, positive semi-definite
    D: np.ndarray  # (n_blocks, 3, 3) float64, N s/m: velocity Jacobian -df/dv, PSD
    energy: dict = field(default_factory=dict)  # J, potential energy per term

    @classmethod
    def zeros(cls, n_nodes: int, pattern: SparsityPattern) -> ForceAccumulator:
        return cls(np.zeros((n_nodes, 3)), pattern.zeros(), pattern.zeros(), {})


class ForceTerm:
    name = "term"

    families: tuple[str, ...] = ()

    def rebuild(self, mesh: Mesh, pattern: SparsityPattern) -> None:
        pass

    def accumulate(self, mesh: Mesh, t: float, acc: ForceAccumulator) -> None:
        raise NotImplementedError

    def add_forces(self, mesh: Mesh, t: float, pattern: SparsityPattern, force: np.ndarray) -> None:
        """Add this term's forces to `force` (n_nodes, 3) in place, without its stiffness.

        The default assembles everything and keeps the forces; the elastic terms, whose stiffness
        is most of their cost, override it (the remesh's pop filter needs the old mesh's forces).
        """
        acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
        self.accumulate(mesh, t, acc)
        force += acc.force


class Membrane(ForceTerm):
    """StVK membrane on the Green strain of each face (cloth.physics.membrane).

    `alpha` (F,) holds each face's compression factor for buckling compensation (paper eq 10;
    all ones, plain StVK, unless the buckling stage sets it after each rebuild).
    """

    name = "membrane"

    def __init__(self, mu: float, lam: float, project: bool = True):
        self.mu, self.lam, self.project = float(mu), float(lam), _hessian_kind(project)

    families = ("faces",)

    def rebuild(self, mesh, pattern):
        self.slots = pattern.slots["faces"]
        F = mesh.n_faces
        self.energy, self.grad, self.hess = np.zeros(F), np.zeros((F, 9)), np.empty((F, 9, 9))
        self.alpha = np.ones(F)

    def elements(self, node_x, face_nodes, face_Dm_inv, face_area, face_alpha, out_energy, out_grad, out_hess,
                 project=None):
        """Energy, gradient and Hessian of the given faces (the pop filter's region; writes the outs);
        `project` as the kernel's (None: this term's own)."""
        membrane_elements(node_x, face_nodes, face_Dm_inv, face_area, self.mu, self.lam,
                          self.project if project is None else project, out_energy, out_grad, out_hess, face_alpha)

    def accumulate(self, mesh, t, acc):
        membrane_elements(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area,
                          self.mu, self.lam, self.project, self.energy, self.grad, self.hess, self.alpha)
        scatter_forces(acc.force, mesh.face_nodes, self.grad, -1.0)
        scatter_blocks(acc.K, self.slots, self.hess, 1.0)
        acc.energy[self.name] = float(self.energy.sum())

    def add_forces(self, mesh, t, pattern, force):
        # the Hessian unprojected: the projection's eigensolves are the costly part, and unused here
        membrane_elements(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area,
                          self.mu, self.lam, False, self.energy, self.grad, self.hess, self.alpha)
        scatter_forces(force, mesh.face_nodes, self.grad, -1.0)


class MeasuredMembrane(Membrane):
    """ARCSim's anisotropic membrane of a measured material (cloth.physics.measured_membrane):
    each face's stiffness is read from the material's table at its strain at the start of each
    evaluation and held fixed in its derivatives, as ARCSim does.

    `alpha` as Membrane's (buckling compensation). `face_k` (F, 4) N/m holds the stiffness of
    the last evaluation.
    """

    def __init__(self, material, project: bool = True):
        self.samples = np.ascontiguousarray(material.stretching_samples)  # (30, 30, 30, 4) N/m
        self.project = bool(project)

    def rebuild(self, mesh, pattern):
        super().rebuild(mesh, pattern)
        self.face_k = np.zeros((mesh.n_faces, 4))

    def elements(self, node_x, face_nodes, face_Dm_inv, face_area, face_alpha, out_energy, out_grad, out_hess,
                 project=None):
        # the measured kernel projects (any true `project`, GAUSS_NEWTON included) or not
        k = np.empty((face_nodes.shape[0], 4))
        measured_membrane_elements(node_x, face_nodes, face_Dm_inv, face_area, self.samples,
                                   self.project if project is None else bool(project),
                                   out_energy, out_grad, out_hess, face_alpha, k)

    def accumulate(self, mesh, t, acc):
        measured_membrane_elements(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area, self.samples,
                                   self.project, self.energy, self.grad, self.hess, self.alpha, self.face_k)
        scatter_forces(acc.force, mesh.face_nodes, self.grad, -1.0)
        scatter_blocks(acc.K, self.slots, self.hess, 1.0)
        acc.energy[self.name] = float(self.energy.sum())

    def add_forces(self, mesh, t, pattern, force):
        # as Membrane.add_forces: the Hessian unprojected, unused
        measured_membrane_elements(mesh.node_x, mesh.face_nodes, mesh.face_Dm_inv, mesh.face_area, self.samples,
                                   False, self.energy, self.grad, self.hess, self.alpha, self.face_k)
        scatter_forces(force, mesh.face_nodes, self.grad, -1.0)


class Bending(ForceTerm):
    """Discrete-shell dihedral-angle bending on interior edges (cloth.physics.bending)."""

    name = "bending"

    def __init__(self, k_bend: float, project: bool | int = True):
        """`project`: the Hessian of cloth.physics.bending.bending_element_into (False, True or
        GAUSS_NEWTON)."""
        self.k_bend, self.project = float(k_bend), _hessian_kind(project)

    families = ("hinges",)

    def rebuild(self, mesh, pattern):
        self.stencil = mesh.edge_stencil()
        self.slots = pattern.slots["hinges"]
        idx = mesh.bending_edges
        fa, fb = mesh.edge_faces[idx, 0], mesh.edge_faces[idx, 1]
        self.weight = np.ascontiguousarray(
            hinge_weight(mesh.edge_rest_length[idx], mesh.face_area[fa], mesh.face_area[fb], self.k_bend))
        self.rest_theta = np.ascontiguousarray(mesh.edge_rest_theta[idx])
        E = idx.size
        self.energy, self.grad, self.hess = np.zeros(E), np.zeros((E, 12)), np.empty((E, 12, 12))

    def accumulate(self, mesh, t, acc):
        bending_elements(mesh.node_x, self.stencil, self.rest_theta, self.weight, self.project,
                         self.energy, self.grad, self.hess)
        scatter_forces(acc.force, self.stencil, self.grad, -1.0)
        scatter_blocks(acc.K, self.slots, self.hess, 1.0)
        acc.energy[self.name] = float(self.energy.sum())

    def add_forces(self, mesh, t, pattern, force):
        # Gauss-Newton: the gradient is the same, the Hessian a cheap outer product (unused here)
        bending_elements(mesh.node_x, self.stencil, self.rest_theta, self.weight, GAUSS_NEWTON,
                         self.energy, self.grad, self.hess)
        scatter_forces(force, self.stencil, self.grad, -1.0)


class MeasuredBending(Bending):
    """Hinge bending with ARCSim's per-edge stiffness of a measured material (cloth.physics.dde):
    each hinge's ke is read at its curvature and material direction at the start of each
    evaluation and held fixed in the derivatives, as ARCSim does; its weight is ARCSim's
    w = ke l^2 / (4 (A_0 + A_1)) (`weight`, refreshed by every accumulate and by rebuild). The
    hinge's Hessian is the isotropic term's (exact at fixed w, projected where indefinite; ARCSim
    keeps only its Gauss-Newton part w grad theta grad theta^T, cloth.physics.bending.GAUSS_NEWTON).
    """

    def __init__(self, material, project: bool | int = True):
        self.bending_samples = np.ascontiguousarray(material.bending)  # (3, 5) N m
        self.project = _hessian_kind(project)

    def rebuild(self, mesh, pattern):
        self.stencil = mesh.edge_stencil()
        self.slots = pattern.slots["hinges"]
        self.rest_theta = np.ascontiguousarray(mesh.edge_rest_theta[mesh.bending_edges])
        self.length, self.area_sum, self.direction = hinge_rest_data(mesh)
        E = self.stencil.shape[0]
        self.ke, self.weight = np.zeros(E), np.zeros(E)
        self.energy, self.grad, self.hess = np.zeros(E), np.zeros((E, 12)), np.empty((E, 12, 12))
        self.update_stiffness(mesh.node_x)

    def update_stiffness(self, node_x):
        """ke (E,) N m and weight (E,) N m of every hinge at the positions `node_x` (into self)."""
        hinge_stiffness(node_x, self.stencil, self.length, self.area_sum, self.direction, self.bending_samples,
                        self.ke, self.weight)

    def accumulate(self, mesh, t, acc):
        self.update_stiffness(mesh.node_x)
        super().accumulate(mesh, t, acc)

    def add_forces(self, mesh, t, pattern, force):
        self.update_stiffness(mesh.node_x)
        super().add_forces(mesh, t, pattern, force)


def _hessian_kind(project) -> bool | int:
    """A bending term's `project`: GAUSS_NEWTON kept as it is, anything else as a bool."""
    return GAUSS_NEWTON if project == GAUSS_NEWTON else bool(project)


class Gravity(ForceTerm):
    """Uniform gravity f = m g; potential energy -sum m g.x."""

    name = "gravity"

    def __init__(self, g):
        self.g = np.asarray(g, dtype=np.float64)

    def accumulate(self, mesh, t, acc):
        acc.force += mesh.node_m[:, None] * self.g
        acc.energy[self.name] = float(-np.sum(mesh.node_m * (mesh.node_x @ self.g)))


class HandleSprings(ForceTerm):
    """The springs of fading handles (ARCSim's handle constraints after their end_time): each node
    of a handle in its fading phase is pulled to its target by k s(t) (target - x), k the handle's
    stiffness and s its strength (cloth.core.scene.Handle); energy k s |target - x|^2 / 2."""

    name = "handle_springs"

    def __init__(self, handles: list):
        self.handles = handles  # the scene's, whose phases the frame loop moves
        self.diag = np.zeros(0, dtype=np.int64)

    def rebuild(self, mesh, pattern):
        self.diag = pattern.diag

    def accumulate(self, mesh, t, acc):
        energy = 0.0
        for h in self.handles:
            if h.state != "fading" or h.nodes.size == 0:
                continue
            k = h.stiffness * h.strength(t)
            d = h.targets(t) - mesh.node_x[h.nodes]
            acc.force[h.nodes] += k * d
            acc.K[self.diag[h.nodes]] += k * np.eye(3)
            energy += 0.5 * k * float((d * d).sum())
        acc.energy[self.name] = energy


@njit(cache=True)
def drag_elements(node_x, node_v, face_nodes, wind, drag, density, drag_tangential, out_force, out_jac):
    """Air drag per face against the wind w, a third of the face's force to each node:

        f = A [(c v_n + rho |v_n| v_n) n + d v_t],   v_rel = w - v_mean,  v_n = v_rel . n,
                                                      v_t = v_rel - v_n n,

    with A the world area and n the unit world normal: a linear normal drag c (kg/(m^2 s)), the
    quadratic pressure of air of density rho (kg/m^3) and a linear tangential drag d
    (kg/(m^2 s)); ARCSim's wind is rho and d (with the material area for A). The velocity
    Jacobian, -df_a/dv_b = A/9 [(c + 2 rho |v_n|) n n^T + d (I - n n^T)], is positive
    semi-definite; the dependence of A and n on positions is neglected, as is usual for drag.
    """
    for f in range(face_nodes.shape[0]):
        i0, i1, i2 = face_nodes[f, 0], face_nodes[f, 1], face_nodes[f, 2]
        e1 = node_x[i1] - node_x[i0]
        e2 = node_x[i2] - node_x[i0]
        n = np.cross(e1, e2)
        ln = np.sqrt(n[0] * n[0] + n[1] * n[1] + n[2] * n[2])
        for a in range(9):
            out_force[f, a] = 0.0
            for b in range(9):
                out_jac[f, a, b] = 0.0
        if ln == 0.0:
            continue
        area = 0.5 * ln
        n = n / ln
        vrel = wind - (node_v[i0] + node_v[i1] + node_v[i2]) / 3.0
        vn = vrel[0] * n[0] + vrel[1] * n[1] + vrel[2] * n[2]
        normal = area * (drag * vn + density * abs(vn) * vn)
        k_n = area * (drag + 2.0 * density * abs(vn)) / 9.0
        k_t = area * drag_tangential / 9.0
        for a in range(3):
            for d in range(3):
                out_force[f, 3 * a + d] = (normal * n[d] + area * drag_tangential * (vrel[d] - vn * n[d])) / 3.0
                for b in range(3):
                    for e in range(3):
                        k = (k_n - k_t) * n[d] * n[e]
                        if d == e:
                            k += k_t
                        out_jac[f, 3 * a + d, 3 * b + e] = k


class Wind(ForceTerm):
    """Air drag against a wind velocity that may gust: w(t) = w0 (1 + g sin(2 pi f t))."""

    name = "wind"

    def __init__(self, velocity, drag: float, gust_amplitude: float = 0.0, gust_frequency: float = 0.0,
                 density: float = 0.0, drag_tangential: float = 0.0):
        self.velocity = np.asarray(velocity, dtype=np.float64)  # m/s
        self.drag = float(drag)  # kg/(m^2 s): normal force per area per unit normal speed
        self.gust_amplitude, self.gust_frequency = float(gust_amplitude), float(gust_frequency)
        self.density = float(density)  # kg/m^3: quadratic normal pressure rho |v_n| v_n (ARCSim's wind)
        self.drag_tangential = float(drag_tangential)  # kg/(m^2 s): tangential drag (ARCSim's wind drag)

    families = ("faces",)

    def rebuild(self, mesh, pattern):
        self.slots = pattern.slots["faces"]
        F = mesh.n_faces
        self.f, self.jac = np.empty((F, 9)), np.empty((F, 9, 9))

    def wind_at(self, t: float) -> np.ndarray:
        return self.velocity * (1.0 + self.gust_amplitude * np.sin(2 * np.pi * self.gust_frequency * t))

    def accumulate(self, mesh, t, acc):
        drag_elements(mesh.node_x, mesh.node_v, mesh.face_nodes, self.wind_at(t), self.drag, self.density,
                      self.drag_tangential, self.f, self.jac)
        scatter_forces(acc.force, mesh.face_nodes, self.f, 1.0)
        scatter_blocks(acc.D, self.slots, self.jac, 1.0)


def element_families(mesh: Mesh, terms: list[ForceTerm]) -> dict[str, np.ndarray]:
    """Node stencils of the element families that `terms` couple, for the sparsity pattern."""
    available = {"faces": lambda: mesh.face_nodes, "hinges": mesh.edge_stencil}
    names = sorted({f for term in terms for f in term.families})
    return {name: available[name]() for name in names}
