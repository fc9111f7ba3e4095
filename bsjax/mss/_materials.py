"""Materials: Young's modulus, density and damping ratio → spring and node parameters.

Thesis §5.2: a Voigt element (spring ‖ damper) with stiffness `K = E A / L` (eq. 5.1), natural
frequency `ω₀ = √(K/m)` (eq. 5.6) and damping ratio `ζ = D / (2 √(K m))` (eq. 5.7).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks
from bsjax._boundary import compiled


class Material(eqx.Module):
    """An isotropic material for the mass-spring lattice.

    **Fields:**
    - `youngs_modulus`: E in N/m² (Pa), > 0.
    - `density`: ρ in kg/m³, > 0.
    - `damping_ratio`: ζ ≥ 0 (dimensionless): 0 undamped, < 1 under-, 1 critically, > 1 over-damped.

    Fields are arrays, so a batch of materials is a `Material` with leading axes (`vmap` over it).
    The values are checked (also when traced: `eqx.error_if`).
    """

    youngs_modulus: Float[Array, "..."]
    density: Float[Array, "..."]
    damping_ratio: Float[Array, "..."]

    def __init__(self, youngs_modulus: ArrayLike, density: ArrayLike, damping_ratio: ArrayLike = 0.1):
        self.youngs_modulus = _checks.positive(
            _checks.array(youngs_modulus, "youngs_modulus"), "youngs_modulus"
        )
        self.density = _checks.positive(_checks.array(density, "density"), "density")
        self.damping_ratio = _checks.positive(
            _checks.array(damping_ratio, "damping_ratio"), "damping_ratio", strict=False
        )


#: Plasticine as in thesis Fig. 5.9: "spring stiffness 13 MN/m², density 2500 kg/m³"; heavily damped.
PLASTICINE = Material(13e6, 2500.0, 1.0)
#: Structural steel: E = 200 GPa, ρ = 7850 kg/m³, light structural damping.
STEEL = Material(200e9, 7850.0, 0.02)
#: A soft gelatine jelly: E ≈ 10 kPa, ρ ≈ 1050 kg/m³, springy.
JELLY = Material(1e4, 1050.0, 0.1)

PRESETS = {"plasticine": PLASTICINE, "steel": STEEL, "jelly": JELLY}


def _stiffness(material, rest_length, area):
    return material.youngs_modulus * area / rest_length


def _damping(material, stiffness, mass):
    return 2.0 * material.damping_ratio * jnp.sqrt(stiffness * mass)


@compiled
def spring_stiffness(material: Material, rest_length, area) -> Float[Array, "..."]:
    """`K = E A / L` in N/m (thesis eq. 5.1) for springs of rest length `L > 0` (m) and
    cross-section `area ≥ 0` (m²)."""
    rest_length = _checks.positive(_checks.array(rest_length, "rest_length"), "rest_length")
    area = _checks.positive(_checks.array(area, "area"), "area", strict=False)
    return _stiffness(material, rest_length, area)


@compiled
def spring_damping(material: Material, stiffness, mass) -> Float[Array, "..."]:
    """`D = 2 ζ √(K m)` in N·s/m, eq. 5.7 solved for D; `stiffness ≥ 0` (N/m) and the spring's
    node `mass > 0` (kg)."""
    stiffness = _checks.positive(_checks.array(stiffness, "stiffness"), "stiffness", strict=False)
    mass = _checks.positive(_checks.array(mass, "mass"), "mass")
    return _damping(material, stiffness, mass)


@compiled
def natural_frequency(stiffness, mass) -> Float[Array, "..."]:
    """`ω₀ = √(K/m)` in rad/s (thesis eq. 5.6), `stiffness ≥ 0`, `mass > 0`."""
    stiffness = _checks.positive(_checks.array(stiffness, "stiffness"), "stiffness", strict=False)
    mass = _checks.positive(_checks.array(mass, "mass"), "mass")
    return jnp.sqrt(stiffness / mass)


@compiled
def damping_ratio(damping, stiffness, mass) -> Float[Array, "..."]:
    """`ζ = D / (2 √(K m))` (thesis eq. 5.7), `damping ≥ 0`, `stiffness > 0`, `mass > 0`."""
    damping = _checks.positive(_checks.array(damping, "damping"), "damping", strict=False)
    stiffness = _checks.positive(_checks.array(stiffness, "stiffness"), "stiffness")
    mass = _checks.positive(_checks.array(mass, "mass"), "mass")
    return damping / (2.0 * jnp.sqrt(stiffness * mass))
