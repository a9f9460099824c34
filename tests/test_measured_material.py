"""Measured materials in ARCSim's format: the loader, the stiffness as ARCSim evaluates it (hand-
computed at sample points and between them), the anisotropic membrane and the per-hinge bending
at fixed stiffness against finite differences, and a short run of a hanging sheet."""

import json
import math

import numpy as np
import pytest
from helpers import COTTON, MEASURED_JSON, random_rest_triangle, write_material

from cloth.core.material import MaterialError
from cloth.core.measured import MeasuredMaterial, load_arcsim_material, stretching_sample
from cloth.core.mesh import grid_mesh
from cloth.core.scene import Scene
from cloth.physics.assembly import SparsityPattern, scatter_forces
from cloth.physics.bending import bending_elements, dihedral_angle
from cloth.physics.buckling import BucklingParams
from cloth.physics.dde import bending_stiffness, edge_direction, hinge_stiffness, stretching_stiffness
from cloth.physics.forces import ForceAccumulator, MeasuredBending, MeasuredMembrane, Membrane
from cloth.physics.measured_membrane import measured_element
from cloth.physics.membrane import stvk_element
from cloth.scenes.registry import hanging_sheet
from cloth.simulation import Simulation
from cloth.view.camera import Camera
from cloth.view.paths import StaticPath

# The table's angle is computed in single precision, as ARCSim does: a value at a sample direction
# is off by a float32 rounding of the angle (~1e-7 of the angle) times the rows' differences.
ANGLE_ROUNDING = 1e-6
# Values computed along the same path in double precision (interpolation weights, sums).
ROUNDOFF = 1e-10
# Central differences with step 1e-6 on O(1) coordinates: truncation ~1e-12, round-off ~1e-10.
FD_STEP = 1e-6
FD_REL_TOL = 1e-5
# A projected Hessian's smallest eigenvalue may be negative by the eigen-solver's round-off.
PSD_TOL = 1e-10
SEED = 11


@pytest.fixture
def material(tmp_path):
    return load_arcsim_material(write_material(tmp_path / "knit.json"))


def _rows():
    return np.array(MEASURED_JSON["stretching"], float)


def _bend():
    return np.array(MEASURED_JSON["bending"], float)


# ---- the loader ------------------------------------------------------------------------------

def test_loader_reads_a_good_file(tmp_path):
    m = load_arcsim_material(write_material(tmp_path / "knit.json"))
    assert m.name == "knit" and m.density == 0.2 and m.strain_limits is None and m.damping == 0.0
    assert np.array_equal(m.stretching, _rows()) and np.array_equal(m.bending, _bend())
    assert m.stretching_samples.shape == (30, 30, 30, 4)
    assert not m.stretching.flags.writeable and not m.stretching_samples.flags.writeable
    assert m.damping_mass == 0.0 and m.damping_stiffness == 0.0
    named = load_arcsim_material(tmp_path / "knit.json", name="shirt", strain_limits=[0.95, 1.05], damping=2e-3)
    assert named.name == "shirt" and named.strain_limits == (0.95, 1.05) and named.damping_stiffness == 2e-3


def test_loader_accepts_comments_as_arcsim_does(tmp_path):
    text = "// thickness: h = 0.1 mm\n/* a block\n comment */\n" + json.dumps(MEASURED_JSON)
    m = load_arcsim_material(write_material(tmp_path / "paper.json", text=text))
    assert m.density == 0.2


@pytest.mark.parametrize("key", ["density", "stretching", "bending"])
def test_a_missing_key_is_named_with_the_file(tmp_path, key):
    data = {k: v for k, v in MEASURED_JSON.items() if k != key}
    path = write_material(tmp_path / "bad.json", data)
    with pytest.raises(MaterialError, match=f"bad.json.*missing key '{key}'") as e:
        load_arcsim_material(path)
    assert e.value.key == key


@pytest.mark.parametrize("key, value", [
    ("stretching", [[1.0, 2.0, 3.0, 4.0]] * 5),  # 5 rows
    ("stretching", [[1.0, 2.0, 3.0]] * 6),  # 3 columns
    ("bending", [[1.0] * 5] * 4),
    ("bending", [[1.0] * 4] * 3),
    ("bending", "stiff"),
])
def test_a_wrong_shape_is_named_with_the_file(tmp_path, key, value):
    path = write_material(tmp_path / "bad.json", {**MEASURED_JSON, key: value})
    with pytest.raises(MaterialError, match=f"bad.json.*{key}") as e:
        load_arcsim_material(path)
    assert e.value.key == key


@pytest.mark.parametrize("density", [0.0, -0.1, "heavy", None])
def test_a_non_positive_density_is_refused(tmp_path, density):
    path = write_material(tmp_path / "bad.json", {**MEASURED_JSON, "density": density})
    with pytest.raises(MaterialError, match="bad.json.*density") as e:
        load_arcsim_material(path)
    assert e.value.key == "density"


@pytest.mark.parametrize("key", ["thicken", "density_mult", "stretching_mult", "bending_mult"])
def test_a_non_positive_multiplier_is_refused(tmp_path, key):
    with pytest.raises(MaterialError, match=key) as e:
        load_arcsim_material(write_material(tmp_path / "knit.json"), **{key: 0.0})
    assert e.value.key == key


def test_unreadable_and_invalid_files_name_the_file(tmp_path):
    with pytest.raises(MaterialError, match="nowhere.json"):
        load_arcsim_material(tmp_path / "nowhere.json")
    with pytest.raises(MaterialError, match="broken.json"):
        load_arcsim_material(write_material(tmp_path / "broken.json", text="{density: "))


@pytest.mark.parametrize("limits", [(1.1, 1.2), (0.9, 0.95), (0.0, 1.1), (-0.5, 1.1), (1.05, 0.95), (0.9,)])
def test_strain_limits_must_bracket_one(tmp_path, limits):
    with pytest.raises(MaterialError, match="strain_limits") as e:
        load_arcsim_material(write_material(tmp_path / "knit.json"), strain_limits=limits)
    assert e.value.key == "strain_limits"


def test_multipliers_and_thicken_apply_as_in_arcsim(tmp_path):
    """ARCSim's conf: every multiplier times thicken, then density, stretching table and bending
    scaled linearly by theirs (src/conf.cpp)."""
    path = write_material(tmp_path / "knit.json")
    base = load_arcsim_material(path)
    m = load_arcsim_material(path, thicken=2.0, density_mult=1.5, stretching_mult=3.0, bending_mult=0.5)
    assert m.density == pytest.approx(0.2 * 1.5 * 2.0, rel=ROUNDOFF)
    assert np.allclose(m.stretching, 6.0 * base.stretching, rtol=ROUNDOFF, atol=0)
    assert np.allclose(m.bending, 1.0 * base.bending, rtol=ROUNDOFF, atol=0)
    # ARCSim scales its tabulated samples; for positive factors that is the table of scaled rows
    assert np.allclose(m.stretching_samples, 6.0 * base.stretching_samples, rtol=ROUNDOFF, atol=0)


def test_a_measured_material_can_be_built_from_arrays_and_checks_them():
    m = MeasuredMaterial("arrays", 0.1, _rows(), _bend())
    assert m.stretching_samples.shape == (30, 30, 30, 4)
    with pytest.raises(MaterialError, match="stretching") as e:
        MeasuredMaterial("arrays", 0.1, _rows()[:5], _bend())
    assert e.value.key == "stretching"
    with pytest.raises(MaterialError, match="density"):
        MeasuredMaterial("arrays", 0.0, _rows(), _bend())


# ---- stretching stiffness, hand-computed ----------------------------------------------------

def _green(F):
    F = np.asarray(F, float)
    E = 0.5 * (F.T @ F - np.eye(2))
    return E[0, 0], E[0, 1], E[1, 1]


def _uniaxial(stretch, angle):
    """Green strain (G00, G01, G11) of a stretch `stretch` along the material direction `angle`."""
    d = np.array([math.cos(angle), math.sin(angle)])
    F = np.eye(2) + (stretch - 1.0) * np.outer(d, d)
    return _green(np.vstack([F, np.zeros((1, 2))]))


def test_stretching_samples_at_hand_computed_strains():
    R = _rows()
    r0 = np.maximum(R[0], 0)
    # no strain, and compression in every direction: the zero-strain row, doubled
    assert np.allclose(stretching_sample(0.0, 0.0, 0.0, R), 2 * r0, rtol=ROUNDOFF)
    assert np.allclose(stretching_sample(-0.1, 0.03, -0.1, R), 2 * r0, rtol=ROUNDOFF)
    # a stretch of 1.1 along u: s = 6 (1.1 - 1) = 0.6 between row 0 and the 0-degree row
    assert np.allclose(stretching_sample(*_uniaxial(1.1, 0.0), R), 2 * (0.4 * R[0] + 0.6 * R[1]), rtol=ROUNDOFF)
    # past 1 + 1/6 the strain weight is clamped at 1 - 1e-6
    s = 1.0 - 1e-6
    assert np.allclose(stretching_sample(*_uniaxial(1.3, 0.0), R), 2 * ((1 - s) * R[0] + s * R[1]), rtol=ROUNDOFF)
    # along v (G01 = 0, G11 > G00): ARCSim's eigenvector is (0, 1), 90 degrees, clamped at 4 - 1e-6
    t = 1.0 - 1e-6
    expected = 2 * np.maximum(0.4 * R[0] + 0.6 * ((1 - t) * R[4] + t * R[5]), 0)
    assert np.allclose(stretching_sample(*_uniaxial(1.1, math.pi / 2), R), expected, rtol=ROUNDOFF)
    # at 45 and 22.5 degrees: the rows of those directions
    for angle, row in ((math.pi / 4, 3), (math.pi / 8, 2)):
        expected = 2 * (0.4 * R[0] + 0.6 * R[row])
        assert np.allclose(stretching_sample(*_uniaxial(1.1, angle), R), expected, rtol=ANGLE_ROUNDING)
    # half way between 0 and 22.5 degrees: half of each row
    expected = 2 * (0.4 * R[0] + 0.6 * 0.5 * (R[1] + R[2]))
    assert np.allclose(stretching_sample(*_uniaxial(1.1, math.pi / 16), R), expected, rtol=ANGLE_ROUNDING)


def test_negative_interpolated_stiffness_is_clamped_to_zero():
    R = _rows()
    k = stretching_sample(0.0, 0.0, 0.0, R)
    assert k[1] == 0.0 and R[0, 1] < 0


def test_the_lookup_returns_the_samples_at_grid_points(material):
    rng = np.random.default_rng(SEED)
    k = np.empty(4)
    for i, j, c in rng.integers(0, 29, size=(20, 3)):
        stretching_stiffness(-0.25 + i / 30, c / 30, -0.25 + j / 30, material.stretching_samples, k)
        assert np.allclose(k, material.stretching_samples[i, j, c], rtol=ROUNDOFF, atol=ROUNDOFF)


def test_the_lookup_between_samples_interpolates_linearly():
    """A material whose stiffness grows with strain only (row 0 zero, rows 1-5 equal): the samples
    along G00 with G11 = -1/4 + 5/30 and G01 = 0 are 2 R 6 (sqrt(1 + 2 G00) - 1), and a strain
    between two of them gets their linear interpolation; the sign of G01 does not count."""
    R = np.array([[0.0] * 4] + [[10.0, 4.0, 30.0, 6.0]] * 5)
    m = MeasuredMaterial("strain-only", 0.1, R, _bend())
    G11 = -0.25 + 5 / 30

    def sample(G00):
        s = min(max(6.0 * (math.sqrt(1.0 + 2.0 * G00) - 1.0), 0.0), 1.0 - 1e-6)
        return 2.0 * s * R[1]

    k = np.empty(4)
    for i, frac in ((8, 0.3), (9, 0.75), (12, 0.5)):  # G00 from 0.017 to 0.167
        G00 = -0.25 + (i + frac) / 30
        stretching_stiffness(G00, 0.0, G11, m.stretching_samples, k)
        expected = (1 - frac) * sample(-0.25 + i / 30) + frac * sample(-0.25 + (i + 1) / 30)
        assert np.allclose(k, expected, rtol=1e-9)
    # the shear axis: |G01| between samples, on a constant material the constant
    const = MeasuredMaterial("constant", 0.1, np.tile([[10.0, 4.0, 30.0, 6.0]], (6, 1)), _bend())
    for G in ((0.013, 0.2071, -0.04), (0.6, -0.31, 0.02), (2.0, 5.0, -1.0)):  # the last beyond the table
        stretching_stiffness(G[0], G[1], G[2], const.stretching_samples, k)
        assert np.allclose(k, [20.0, 8.0, 60.0, 12.0], rtol=ROUNDOFF)
    a, b = np.empty(4), np.empty(4)
    stretching_stiffness(0.1, 0.07, 0.02, m.stretching_samples, a)
    stretching_stiffness(0.1, -0.07, 0.02, m.stretching_samples, b)
    assert np.array_equal(a, b)


# ---- bending stiffness, hand-computed ----------------------------------------------------------

def test_bending_stiffness_at_hand_computed_curvatures_and_directions():
    B = _bend()
    along_u, diagonal, along_v = edge_direction(1.0, 0.0), edge_direction(1.0, 1.0), edge_direction(0.0, 2.0)
    assert along_u == 0.0 and along_v == pytest.approx(2.0, rel=ANGLE_ROUNDING)
    assert diagonal == pytest.approx(1.0, rel=ANGLE_ROUNDING)
    assert bending_stiffness(0.0, along_u, B) == B[0, 0]
    assert bending_stiffness(15.0, along_u, B) == pytest.approx(0.5 * (B[0, 1] + B[0, 2]), rel=ROUNDOFF)
    assert bending_stiffness(15.0, diagonal, B) == pytest.approx(0.5 * (B[1, 1] + B[1, 2]), rel=ANGLE_ROUNDING)
    assert bending_stiffness(0.0, along_v, B) == pytest.approx(B[2, 0], rel=ROUNDOFF)
    mid = edge_direction(math.cos(math.pi / 8), math.sin(math.pi / 8))  # 22.5 degrees: half way
    expected = 0.25 * (B[0, 1] + B[0, 2] + B[1, 1] + B[1, 2])
    assert bending_stiffness(15.0, mid, B) == pytest.approx(expected, rel=ANGLE_ROUNDING)
    # beyond the last sample: clamped at curvature 40 1/m
    assert bending_stiffness(100.0, along_u, B) == pytest.approx(B[0, 4], rel=ROUNDOFF)


def test_edge_direction_folds_every_quadrant():
    """An edge and its reverse, and its mirror images about u and v, have one direction."""
    d = edge_direction(math.cos(math.pi / 6), math.sin(math.pi / 6))
    assert d == pytest.approx(2.0 / 3.0, rel=ANGLE_ROUNDING)
    for angle in (-math.pi / 6, 5 * math.pi / 6, 7 * math.pi / 6, -5 * math.pi / 6):
        assert edge_direction(math.cos(angle), math.sin(angle)) == pytest.approx(d, rel=ANGLE_ROUNDING)
    # 60 degrees is 30 from v: 2 - 2/3
    assert edge_direction(math.cos(math.pi / 3), math.sin(math.pi / 3)) == pytest.approx(4.0 / 3.0, rel=ANGLE_ROUNDING)


def test_negative_curvature_extrapolates_as_arcsim_does():
    """ARCSim clamps its curvature coordinate from above only, and C's cast truncates towards zero:
    a fold of the other sense extrapolates the first two samples (clamped at zero stiffness)."""
    B = _bend()
    assert bending_stiffness(-5.0, 0.0, B) == pytest.approx(1.5 * B[0, 0] - 0.5 * B[0, 1], rel=ROUNDOFF)
    assert bending_stiffness(-30.0, 0.0, B) == 0.0  # 4 B00 - 3 B01 < 0


def test_hinge_stiffness_and_weight_of_a_folded_pair(material):
    """Two faces (a 1x1 grid), the second folded about their shared diagonal: ke at ARCSim's
    curvature -theta l / (A0 + A1) and direction 45 degrees, w = ke l^2 / (4 (A0 + A1))."""
    mesh = grid_mesh(0.1, 0.1, 1, 1, diagonal="none")
    mesh.update_rest_data(material.density)
    x = mesh.node_x.copy()
    x[2, 2] = 0.02  # lift the corner of the second face off the diagonal (nodes 0 and 3)
    mesh.node_x[:] = x
    term = MeasuredBending(material)
    term.rebuild(mesh, SparsityPattern(mesh.n_nodes, {"hinges": mesh.edge_stencil()}))
    s = term.stencil[0]
    theta = dihedral_angle(x[s[0]], x[s[1]], x[s[2]], x[s[3]])
    l, area = math.sqrt(0.02), 0.01
    curvature = -theta * l / area
    ke = bending_stiffness(curvature, edge_direction(1.0, 1.0), material.bending)
    assert term.length[0] == pytest.approx(l, rel=ROUNDOFF) and term.area_sum[0] == pytest.approx(area, rel=ROUNDOFF)
    assert term.ke[0] == pytest.approx(ke, rel=ROUNDOFF)
    assert term.weight[0] == pytest.approx(ke * l * l / (4 * area), rel=ROUNDOFF)
    ke_out, w_out = np.empty(1), np.empty(1)
    hinge_stiffness(x, term.stencil, term.length, term.area_sum, term.direction, material.bending, ke_out, w_out)
    assert ke_out[0] == term.ke[0] and w_out[0] == term.weight[0]


# ---- the membrane at fixed stiffness -----------------------------------------------------------

def _membrane_cases():
    """(rest inverse, area, positions (9,)): general, stretched, compressed both ways, one-sided."""
    rng = np.random.default_rng(SEED)
    for seed in range(3):
        u, B, A = random_rest_triangle(seed)
        x0 = np.column_stack([u, np.zeros(3)])
        for scale, noise in (((1, 1, 1), 0.3), ((1.3, 1.1, 1), 0.01), ((0.7, 0.8, 1), 0.01), ((1.2, 0.6, 1), 0.01)):
            yield B, A, (x0 * scale + noise * rng.standard_normal((3, 3))).reshape(-1)


CASES = list(_membrane_cases())
STIFFNESS = [np.array([80.0, 30.0, 150.0, 40.0]),  # C positive definite
             np.array([80.0, 150.0, 150.0, 40.0])]  # k1^2 > k0 k2: C indefinite


def _element(x, B, A, k, alpha, project=False, lookup=False, samples=None):
    samples = np.zeros((30, 30, 30, 4)) if samples is None else samples
    return measured_element(x[0:3], x[3:6], x[6:9], B, A, samples, alpha, project, k.copy(), lookup)


def _fd(f, x):
    out = []
    for i in range(x.size):
        e = np.zeros_like(x)
        e[i] = FD_STEP
        out.append((f(x + e) - f(x - e)) / (2 * FD_STEP))
    return np.array(out)


def _rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


@pytest.mark.slow
@pytest.mark.parametrize("alpha", [1.0, 0.3, 0.0])
@pytest.mark.parametrize("case", range(len(CASES)))
def test_membrane_gradient_and_hessian_at_fixed_stiffness_match_finite_differences(case, alpha):
    B, A, x = CASES[case]
    k = STIFFNESS[case % 2]
    W, g, H = _element(x, B, A, k, alpha)
    if np.linalg.norm(g) == 0.0:  # alpha = 0 and both directions compressed: no energy at all
        assert W == 0.0 and not np.any(H)
        return
    assert _rel(g, _fd(lambda y: _element(y, B, A, k, alpha)[0], x)) < FD_REL_TOL
    assert _rel(H, _fd(lambda y: _element(y, B, A, k, alpha)[1], x).T) < FD_REL_TOL
    assert np.array_equal(H, H.T)


def test_the_gradient_is_arcsims_stretching_force():
    """ARCSim's force, written as in its stretching_force: with D = Dm^-T [[-1, 1, 0], [-1, 0, 1]]
    (rows du, dv), Du = du^T kron I3, fuu = Du^T x_u, fvv = Dv^T x_v, fuv = (Du^T x_v + Dv^T x_u)/2,
    grad = A (k0 G00 fuu + k2 G11 fvv + k1 (G00 fvv + G11 fuu) + 2 k3 G01 fuv)."""
    k = STIFFNESS[0]
    for B, A, x in CASES:
        X = x.reshape(3, 3).T  # columns: the nodes
        D = B.T @ np.array([[-1.0, 1.0, 0.0], [-1.0, 0.0, 1.0]])
        Du, Dv = np.kron(D[0][None, :], np.eye(3)), np.kron(D[1][None, :], np.eye(3))
        xu, xv = X @ D[0], X @ D[1]
        G = 0.5 * (np.array([[xu @ xu, xu @ xv], [xv @ xu, xv @ xv]]) - np.eye(2))
        fuu, fvv, fuv = Du.T @ xu, Dv.T @ xv, 0.5 * (Du.T @ xv + Dv.T @ xu)
        arcsim = A * (k[0] * G[0, 0] * fuu + k[2] * G[1, 1] * fvv + k[1] * (G[0, 0] * fvv + G[1, 1] * fuu)
                      + 2 * k[3] * G[0, 1] * fuv)
        _, g, _ = _element(x, B, A, k, 1.0)
        assert np.allclose(g, arcsim, rtol=0, atol=ROUNDOFF * np.abs(arcsim).max())


@pytest.mark.parametrize("alpha", [1.0, 0.3, 0.0])
def test_isotropic_stiffness_reproduces_the_stvk_membrane_with_its_buckling_filter(alpha):
    """k = (2 mu + lam, lam, 2 mu + lam, 2 mu) is StVK: energy, gradient and Hessian agree with the
    isotropic kernel (cloth.physics.membrane), eq 10's filter included."""
    mu, lam = 3.0, 2.0
    k = np.array([2 * mu + lam, lam, 2 * mu + lam, 2 * mu])
    for B, A, x in CASES:
        W, g, H = _element(x, B, A, k, alpha)
        W0, g0, H0 = stvk_element(x[0:3], x[3:6], x[6:9], B, A, mu, lam, False, alpha)
        assert W == pytest.approx(W0, rel=ROUNDOFF, abs=ROUNDOFF)
        assert np.allclose(g, g0, rtol=0, atol=ROUNDOFF * max(1.0, np.abs(g0).max()))
        assert np.allclose(H, H0, rtol=0, atol=ROUNDOFF * max(1.0, np.abs(H0).max()))


@pytest.mark.parametrize("alpha", [1.0, 0.3])
def test_projected_membrane_hessian_is_psd_and_exact_where_already_psd(alpha):
    for n, (B, A, x) in enumerate(CASES):
        for k in STIFFNESS:
            _, _, H = _element(x, B, A, k, alpha)
            _, _, P = _element(x, B, A, k, alpha, project=True)
            scale = np.abs(H).max()
            assert np.linalg.eigvalsh(P).min() >= -PSD_TOL * scale, (n, k)
            if np.linalg.eigvalsh(H).min() >= 0:
                assert np.allclose(P, H, atol=PSD_TOL * scale)


@pytest.mark.slow
def test_the_force_holds_the_stiffness_fixed_and_is_not_the_gradient_of_the_looked_up_energy(material):
    """ARCSim's choice: the element's gradient is that of the energy at the stiffness read at the
    current strain, with dk/dx left out; where the stiffness varies with strain, the energy
    W(x, k(x)) has another gradient."""
    B, A, x = CASES[1]  # stretched by 1.1-1.3: the table's stiffness grows with the strain there
    samples = material.stretching_samples
    k = np.empty(4)
    W, g, _ = measured_element(x[0:3], x[3:6], x[6:9], B, A, samples, 1.0, False, k, True)  # writes k
    W_fixed, g_fixed, _ = _element(x, B, A, k, 1.0)
    assert W == W_fixed and np.array_equal(g, g_fixed)
    total = _fd(lambda y: _element(y, B, A, np.empty(4), 1.0, lookup=True, samples=samples)[0], x)
    assert _rel(g, total) > 1e-3


# ---- the measured bending at fixed stiffness ---------------------------------------------------

def test_measured_bending_force_and_stiffness_are_the_derivatives_at_fixed_weights(material):
    """The term's force is -grad and its K (unprojected) the Hessian of sum 1/2 w_e theta_e^2 with
    the weights read at the start."""
    mesh = grid_mesh(0.2, 0.2, 2, 2)
    mesh.update_rest_data(material.density)
    rng = np.random.default_rng(SEED)
    mesh.node_x[:, 2] += 0.03 * rng.standard_normal(mesh.n_nodes)
    pattern = SparsityPattern(mesh.n_nodes, {"hinges": mesh.edge_stencil()})
    term = MeasuredBending(material, project=False)
    term.rebuild(mesh, pattern)
    acc = ForceAccumulator.zeros(mesh.n_nodes, pattern)
    term.accumulate(mesh, 0.0, acc)
    weight = term.weight.copy()
    assert np.all(weight > 0)
    E = weight.size
    e, g, H = np.empty(E), np.empty((E, 12)), np.empty((E, 12, 12))

    def energy(x):
        bending_elements(x.reshape(-1, 3), term.stencil, term.rest_theta, weight, False, e, g, H)
        return e.sum()

    def gradient(x):
        bending_elements(x.reshape(-1, 3), term.stencil, term.rest_theta, weight, False, e, g, H)
        out = np.zeros((mesh.n_nodes, 3))
        scatter_forces(out, term.stencil, g, 1.0)
        return out.reshape(-1)

    x = mesh.node_x.reshape(-1).copy()
    assert _rel(-acc.force.reshape(-1), _fd(energy, x)) < FD_REL_TOL
    K = pattern.to_scipy(acc.K).toarray()
    assert _rel(K, _fd(gradient, x).T) < FD_REL_TOL


# ---- scenes and simulation ----------------------------------------------------------------------

def test_a_scene_takes_its_mass_from_the_measured_density(material):
    mesh = grid_mesh(0.5, 0.4, 5, 4)
    scene = Scene("sheet", mesh, material, frozenset({"membrane", "bending"}), frame_time=0.04, steps_per_frame=2)
    assert scene.mesh.node_m.sum() == pytest.approx(0.2 * 0.5 * 0.4, rel=ROUNDOFF)
    sim = Simulation(scene)
    assert [type(t) for t in sim.terms] == [MeasuredMembrane, MeasuredBending]


def test_a_hanging_sheet_of_measured_material_runs_stably(material):
    scene = hanging_sheet(material, resolution=8, size=0.4, effects=("membrane", "bending", "gravity"))
    z0 = scene.mesh.node_x[:, 2].mean()
    sim = Simulation(scene)
    for _ in range(8):
        record = sim.advance_frame()
        assert np.all(np.isfinite(sim.mesh.node_x)) and record["max_speed_m_s"] < 5.0
        assert np.isfinite(record["potential_energy_j"]) and record["elastic_energy_j"] >= 0
    assert sim.mesh.node_x[:, 2].mean() < z0 - 0.05  # it swung down
    membrane = next(t for t in sim.terms if isinstance(t, MeasuredMembrane))
    assert np.all(membrane.face_k >= 0) and np.all(membrane.face_k <= material.stretching_samples.max())
    assert record["strain_violation_max"] == 0.0 and record["strain_limit_iterations"] == 0


def test_buckling_compensation_runs_on_a_measured_material(material):
    """Out-of-frustum faces get alpha < 1 and the measured membrane filters their compression."""
    scene = hanging_sheet(material, resolution=8, size=0.4, effects=("membrane", "bending", "gravity"))
    scene.camera = StaticPath(Camera(position=(0.0, -1.0, 1.0), look_at=(0.5, 0.0, 0.8)))  # a third out of frame
    sim = Simulation(scene, buckling=BucklingParams(mode="uniform"))  # alpha = 0 out of frame (equal areas)
    for _ in range(3):
        record = sim.advance_frame()
    assert record["faces_compensated"] > 0 and np.isfinite(record["compressive_energy_out_j"])
    assert np.all(np.isfinite(sim.mesh.node_x))


def test_the_isotropic_material_keeps_its_terms():
    scene = hanging_sheet(COTTON, resolution=4, size=0.4)
    assert [type(t) for t in Simulation(scene).terms][:1] == [Membrane]
