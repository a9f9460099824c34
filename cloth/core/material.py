"""Cloth materials: area density, in-plane elasticity, bending stiffness and damping.

In-plane quantities are those of a thin sheet (per unit area or per unit width), the way
cloth is measured: a 2D Young's modulus in N/m is the 3D modulus times the thickness.
"""

from __future__ import annotations

from dataclasses import dataclass


def lame_parameters(youngs_modulus: float, poisson: float) -> tuple[float, float]:
    """2D plane-stress Lamé parameters: mu = Y / (2 (1 + nu)), lam = Y nu / (1 - nu^2), in N/m."""
    return youngs_modulus / (2.0 * (1.0 + poisson)), youngs_modulus * poisson / (1.0 - poisson * poisson)


class MaterialError(ValueError):
    """A material parameter outside its physical range; `key` names the parameter."""

    def __init__(self, key: str, message: str):
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class Material:
    name: str
    density: float  # kg/m^2, area density
    youngs_modulus: float  # N/m, 2D (membrane) Young's modulus
    poisson_ratio: float  # dimensionless, in [0, 0.5)
    bending_stiffness: float  # N*m (= J), bending rigidity of the sheet
    damping_mass: float = 0.0  # 1/s, Rayleigh mass-proportional damping alpha
    damping_stiffness: float = 0.0  # s, Rayleigh stiffness-proportional damping beta

    def __post_init__(self) -> None:
        checks = {
            "density": self.density > 0,
            "youngs_modulus": self.youngs_modulus > 0,
            "poisson_ratio": 0.0 <= self.poisson_ratio < 0.5,
            "bending_stiffness": self.bending_stiffness >= 0,
            "damping_mass": self.damping_mass >= 0,
            "damping_stiffness": self.damping_stiffness >= 0,
        }
        for key, ok in checks.items():
            if not ok:
                raise MaterialError(key, f"material {self.name!r}: {key} = {getattr(self, key)!r} is out of range")

    def lame(self) -> tuple[float, float]:
        """2D plane-stress Lamé parameters (mu, lambda) in N/m."""

        return lame_parameters(self.youngs_modulus, self.poisson_ratio)
