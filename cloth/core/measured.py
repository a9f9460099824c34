"""Measured cloth materials in ARCSim's format (Wang, Ramamoorthi and O'Brien 2011, "Data-driven
elastic models for cloth"; used by Narain, Samii and O'Brien 2012).

A material file is JSON with three keys:

* ``density``: area density, kg/m^2;
* ``stretching``: 6 rows of 4 numbers (k0, k1, k2, k3). Row 0 holds the stiffness at zero
  strain (for every direction); rows 1-5 the stiffness at a principal stretch of 1 + 1/6 with
  its direction at 0, 22.5, 45, 67.5 and 90 degrees from the material u axis (warp);
* ``bending``: 3 rows of 5 numbers. Row r holds the stiffness of a hinge whose edge makes an
  angle of 45 r degrees with the material u axis; column c the stiffness at ARCSim's curvature
  theta l / (A_0 + A_1) = 10 c m^-1 (theta the dihedral angle, l the rest edge length, A the two
  rest face areas).

Units, as ARCSim's physics uses the numbers (src/physics.cpp, src/dde.cpp). The stretching
energy of a face of rest area A with Green strain G = 1/2 (F^T F - I) is

    W = A/2 (k0 G00^2 + 2 k1 G00 G11 + k2 G11^2 + 2 k3 G01^2)          (J)

with k = 2 x (the file's numbers interpolated): k and the file's stretching numbers are in N/m
(J/m^2, G is dimensionless); ARCSim doubles the interpolated file values, and clamps them at 0,
when it tabulates them (:func:`stretching_sample`). The bending energy of a hinge is

    W = ke l^2 / (2 (A_0 + A_1)) (theta - theta_rest)^2 / 4              (J)

so ke and the file's bending numbers are in N m (= J): ke of about 2e-5 N m for a t-shirt
knit. (ARCSim's ke sits in the hinge weight w = ke l^2 / (4 (A_0 + A_1)) of W = 1/2 w theta^2;
the isotropic path's k_bend sits in w = 3 k_bend l^2 / (A_0 + A_1), so an ARCSim ke is 12
k_bend.)

ARCSim's conf applies four multipliers to a material (src/conf.cpp, ``parse(Cloth::Material*&)``):
``thicken`` multiplies the three others, and then density x density_mult, every stretching
stiffness x stretching_mult and every bending stiffness x bending_mult, all linearly. So
``thicken = 2`` doubles the mass, the stretching and the bending alike: stacked unbonded layers
(bending, which grows with the cube of a solid sheet's thickness, grows linearly too). ARCSim
scales its tabulated stretching samples; for positive multipliers that is the same as scaling the
file's rows, which this module stores scaled (:attr:`MeasuredMaterial.stretching`) beside the
tabulated samples (:attr:`MeasuredMaterial.stretching_samples`).

ARCSim tabulates the stretching stiffness once per material on a 30 x 30 x 30 grid of Green
strains, G00, G11 in -0.25 + i/30 and G01 in i/30 (i = 0..29), and interpolates that table
trilinearly in every step (cloth.physics.dde.stretching_stiffness). Each sample interpolates
the file's rows linearly in the larger principal stretch, between 1 and 1 + 1/6 (clamped: any
stretch beyond 1 + 1/6 uses rows 1-5, any compression row 0), and in the direction of that
stretch, between the five directions of rows 1-5 (a direction beyond 90 degrees uses the 90
degree row; the table's G01 >= 0 keeps directions within [0, 90] degrees, and the lookup reads
|G01|). ARCSim computes the direction with single-precision atan2f and fabsf; this module rounds
the same values to single precision. (A libm's atan2f may still differ from the correctly
rounded value by one unit in the last place: against ARCSim's dde.cpp compiled with glibc, the
tables of its ten cloth materials agree to 2e-7 of their largest stiffness.)
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numba import njit

from cloth.core.jsonc import strip_json_comments
from cloth.core.material import MaterialError

# ARCSim's grid of tabulated Green strains: STRETCH_SAMPLES per axis, the diagonal axes from
# STRETCH_G_MIN in steps of 1 / STRETCH_SAMPLES, the off-diagonal one from 0 (src/dde.cpp).
STRETCH_SAMPLES = 30
STRETCH_G_MIN = -0.25
# Shapes of the file's arrays: stretching rows x (k0, k1, k2, k3); bending directions x curvatures.
STRETCHING_SHAPE = (6, 4)
BENDING_SHAPE = (3, 5)
# The stretch at which the file's rows 1-5 are measured: 1 + 1/STRETCH_PER_ROW.
STRETCH_PER_ROW = 6.0
# The upper clamps of ARCSim's interpolation weights (so that index + 1 stays in the table).
ANGLE_CLAMP = 4.0 - 1e-6
STRAIN_CLAMP = 1.0 - 1e-6


@njit(cache=True)
def stretching_sample(G00, G01, G11, rows):
    """Stiffness (k0, k1, k2, k3) in N/m of ARCSim's table at the Green strain G (one sample).

    `rows` (6, 4) are the file's stretching rows, N/m. With C = 2 G + I = F^T F, l1 its larger
    eigenvalue and (V0, V1) its eigenvector (ARCSim's closed form, src/vectors.cpp), the larger
    principal stretch is w = sqrt(l1) and its direction phi = atan2(V1, V0):

        s = clamp(6 (w - 1), 0, 1 - 1e-6),           a = clamp(8 |phi| / pi, 0, 4 - 1e-6),
        i = floor(a),  t = a - i,
        k = 2 max(0, (1 - s)(1 - t) r0 + s (1 - t) r_{1+i} + (1 - s) t r0 + s t r_{2+i})

    (r0 the zero-strain row, r_{1..5} the rows of the five directions; max componentwise).
    """
    a = 2.0 * G00 + 1.0
    b = 2.0 * G01
    d = 2.0 * G11 + 1.0
    amd = a - d
    disc = math.sqrt(4.0 * b * b + amd * amd)
    l1 = 0.5 * (a + d + disc)
    if b != 0.0:
        v0 = l1 - d
        vn = math.sqrt(v0 * v0 + b * b)
        V0, V1 = v0 / vn, b / vn
    elif a >= d:
        V0, V1 = 1.0, 0.0
    else:
        V0, V1 = 0.0, 1.0
    # fabsf(atan2f(V1, V0) / M_PI) * 8, in ARCSim's single precision
    phi = np.float32(math.atan2(np.float64(np.float32(V1)), np.float64(np.float32(V0))))
    angle = np.float64(np.float32(abs(np.float64(phi) / math.pi))) * 8.0
    angle = min(max(angle, 0.0), ANGLE_CLAMP)
    ia = int(angle)
    t = angle - ia
    s = (math.sqrt(l1) - 1.0) * STRETCH_PER_ROW
    s = min(max(s, 0.0), STRAIN_CLAMP)
    k = np.empty(4)
    for c in range(4):
        v = (rows[0, c] * (1.0 - s) * (1.0 - t) + rows[1 + ia, c] * s * (1.0 - t)
             + rows[0, c] * (1.0 - s) * t + rows[2 + ia, c] * s * t)
        k[c] = 2.0 * max(v, 0.0)
    return k


@njit(cache=True)
def stretching_samples(rows):
    """ARCSim's table (STRETCH_SAMPLES^3, 4) of :func:`stretching_sample`, N/m, at
    G00 = -0.25 + i/30, G11 = -0.25 + j/30, G01 = k/30 (indices [i, j, k])."""
    n = STRETCH_SAMPLES
    out = np.empty((n, n, n, 4))
    for i in range(n):
        for j in range(n):
            for k in range(n):
                out[i, j, k] = stretching_sample(STRETCH_G_MIN + i / (n * 1.0), k / (n * 1.0),
                                                 STRETCH_G_MIN + j / (n * 1.0), rows)
    return out


def _readonly(a) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class MeasuredMaterial:
    """A measured, anisotropic, strain-dependent cloth material (ARCSim's; module docstring).

    Multipliers are already applied: this is the material the physics sees. The isotropic
    :class:`cloth.core.material.Material` and this class both give a Scene its `density`;
    the force terms (cloth.stages.build_force_terms) choose the physics by the type.
    """

    name: str
    density: float  # kg/m^2, area density (x thicken x density_mult)
    stretching: np.ndarray  # (6, 4) float64, N/m: the file's rows (x thicken x stretching_mult)
    bending: np.ndarray  # (3, 5) float64, N m: edge direction x curvature (x thicken x bending_mult)
    strain_limits: tuple | None = None  # (min, max) principal stretches of every face, or None
    damping: float = 0.0  # s, ARCSim's stiffness-proportional damping (Rayleigh beta)
    source: str = ""  # the file it was read from, for messages
    # derived: ARCSim's table of stretching stiffness, (30, 30, 30, 4) float64, N/m
    stretching_samples: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        where = f"material {self.name!r}" + (f" ({self.source})" if self.source else "")
        stretching, bending = _readonly(self.stretching), _readonly(self.bending)
        for key, a, shape in (("stretching", stretching, STRETCHING_SHAPE), ("bending", bending, BENDING_SHAPE)):
            if a.shape != shape:
                raise MaterialError(key, f"{where}: {key} must have shape {shape}, got {a.shape}")
            if not np.all(np.isfinite(a)):
                raise MaterialError(key, f"{where}: {key} has non-finite values")
        if not (math.isfinite(self.density) and self.density > 0):
            raise MaterialError("density", f"{where}: density = {self.density!r} kg/m^2 must be > 0")
        if not (math.isfinite(self.damping) and self.damping >= 0):
            raise MaterialError("damping", f"{where}: damping = {self.damping!r} s must be >= 0")
        limits = None
        if self.strain_limits is not None:
            limits = check_strain_limits(self.strain_limits, where)
        object.__setattr__(self, "stretching", stretching)
        object.__setattr__(self, "bending", bending)
        object.__setattr__(self, "strain_limits", limits)
        object.__setattr__(self, "stretching_samples", _readonly(stretching_samples(stretching)))

    # The names the frame loop reads from either material type (cloth.simulation).
    @property
    def damping_mass(self) -> float:
        """1/s: ARCSim has no mass-proportional damping."""
        return 0.0

    @property
    def damping_stiffness(self) -> float:
        """s: ARCSim's `damping`, the Rayleigh stiffness-proportional coefficient beta."""
        return self.damping


def check_strain_limits(limits, where: str = "strain_limits") -> tuple[float, float]:
    """(min, max) as floats, or MaterialError('strain_limits'): 0 < min <= 1 <= max (max may be inf)."""
    try:
        lo, hi = (float(v) for v in limits)
    except (TypeError, ValueError):
        raise MaterialError("strain_limits", f"{where}: strain_limits must be two numbers (min, max), "
                                             f"got {limits!r}") from None
    if not (0.0 < lo <= 1.0 <= hi) or math.isnan(hi) or math.isinf(lo):
        raise MaterialError("strain_limits", f"{where}: strain_limits = ({lo}, {hi}) must satisfy "
                                             f"0 < min <= 1 <= max (principal stretches)")
    return lo, hi


def load_arcsim_material(path, *, thicken: float = 1.0, density_mult: float = 1.0, stretching_mult: float = 1.0,
                         bending_mult: float = 1.0, strain_limits=None, name: str | None = None,
                         damping: float = 0.0) -> MeasuredMaterial:
    """Read an ARCSim material file (``density``, ``stretching`` 6x4, ``bending`` 3x5; JSON with
    comments allowed, as ARCSim reads it) and apply
    ARCSim's conf multipliers: density x thicken x density_mult, stretching x thicken x
    stretching_mult, bending x thicken x bending_mult (module docstring).

    `strain_limits` (min, max) and `damping` (s) are the other keys of an ARCSim conf's material
    block; `name` defaults to the file's stem. MaterialError names the key and the file: a
    missing key, an array of the wrong shape, a non-positive density or multiplier.
    """
    path = Path(path)
    where = str(path)
    try:
        text = path.read_text()
    except OSError as e:
        raise MaterialError("path", f"cannot read material file {where}: {e}") from None
    try:
        data = json.loads(strip_json_comments(text))
    except ValueError as e:  # json.JSONDecodeError, or a /* comment never closed
        raise MaterialError("path", f"{where} is not valid JSON: {e}") from None
    if not isinstance(data, dict):
        raise MaterialError("path", f"{where}: expected a JSON object with density, stretching and bending")
    for key in ("density", "stretching", "bending"):
        if key not in data:
            raise MaterialError(key, f"{where}: missing key {key!r}")
    for key, value in (("thicken", thicken), ("density_mult", density_mult),
                       ("stretching_mult", stretching_mult), ("bending_mult", bending_mult)):
        if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
            raise MaterialError(key, f"{where}: {key} = {value!r} must be > 0")
    arrays = {}
    for key, shape in (("stretching", STRETCHING_SHAPE), ("bending", BENDING_SHAPE)):
        try:
            a = np.array(data[key], dtype=np.float64)
        except (TypeError, ValueError):
            raise MaterialError(key, f"{where}: {key} must be a {shape[0]}x{shape[1]} array of numbers") from None
        if a.shape != shape:
            raise MaterialError(key, f"{where}: {key} must have shape {shape}, got {a.shape}")
        arrays[key] = a
    density = data["density"]
    if isinstance(density, bool) or not isinstance(density, (int, float)) or not density > 0:
        raise MaterialError("density", f"{where}: density = {density!r} must be a number > 0 (kg/m^2)")
    return MeasuredMaterial(
        name=path.stem if name is None else str(name),
        density=float(density) * (density_mult * thicken),
        stretching=arrays["stretching"] * (thicken * stretching_mult),
        bending=arrays["bending"] * (thicken * bending_mult),
        strain_limits=strain_limits, damping=float(damping), source=where)
