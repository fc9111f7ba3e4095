"""Materials: Young's modulus, density and damping ratio → spring and node parameters.

Thesis §5.2: a Voigt element (spring ‖ damper) with stiffness `K = E A / L` (eq. 5.1), natural
frequency `ω₀ = √(K/m)` (eq. 5.6) and damping ratio `ζ = D / (2 √(K m))` (eq. 5.7).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Float

from bsjax import _checks


class Material(eqx.Module):
    """An isotropic material for the mass-spring lattice.

    **Fields:**
    - `youngs_modulus`: E in N/m² (Pa).
    - `density`: ρ in kg/m³.
    - `damping_ratio`: ζ (dimensionless): 0 undamped, < 1 under-, 1 critically, > 1 over-damped.

    Fields are arrays, so a batch of materials is a `Material` with leading axes (`vmap` over it).
    """

    youngs_modulus: Float[Array, "..."]
    density: Float[Array, "..."]
    damping_ratio: Float[Array, "..."]

    def __init__(self, youngs_modulus: ArrayLike, density: ArrayLike, damping_ratio: ArrayLike = 0.1):
        for name, value, strict in (
            ("youngs_modulus", youngs_modulus, True),
            ("density", density, True),
            ("damping_ratio", damping_ratio, False),
        ):
            _checks.check_positive(value, name, strict=strict)
        self.youngs_modulus = jnp.asarray(youngs_modulus)
        self.density = jnp.asarray(density)
        self.damping_ratio = jnp.asarray(damping_ratio)


#: Plasticine as in thesis Fig. 5.9: "spring stiffness 13 MN/m², density 2500 kg/m³"; heavily damped.
PLASTICINE = Material(13e6, 2500.0, 1.0)
#: Structural steel: E = 200 GPa, ρ = 7850 kg/m³, light structural damping.
STEEL = Material(200e9, 7850.0, 0.02)
#: A soft gelatine jelly: E ≈ 10 kPa, ρ ≈ 1050 kg/m³, springy.
JELLY = Material(1e4, 1050.0, 0.1)

PRESETS = {"plasticine": PLASTICINE, "steel": STEEL, "jelly": JELLY}


def spring_stiffness(material: Material, rest_length, area) -> Float[Array, "..."]:
    """`K = E A / L` in N/m (thesis eq. 5.1) for springs of cross-section `area` (m²)."""
    return material.youngs_modulus * area / rest_length


def spring_damping(material: Material, stiffness, mass) -> Float[Array, "..."]:
    """`D = 2 ζ √(K m)` in N·s/m, eq. 5.7 solved for D; `mass` is the spring's node mass (kg)."""
    return 2.0 * material.damping_ratio * jnp.sqrt(stiffness * mass)


def natural_frequency(stiffness, mass) -> Float[Array, "..."]:
    """`ω₀ = √(K/m)` in rad/s (thesis eq. 5.6)."""
    return jnp.sqrt(stiffness / mass)


def damping_ratio(damping, stiffness, mass) -> Float[Array, "..."]:
    """`ζ = D / (2 √(K m))` (thesis eq. 5.7)."""
    return damping / (2.0 * jnp.sqrt(stiffness * mass))
