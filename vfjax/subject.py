"""The subject's constants: vocal-fold geometry, mass, and the air that drives it."""

from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import ArrayLike

from ._validate import as_parameter, check_constraints, constraints_hold, positive


class Subject(eqx.Module):
    """What stays fixed for one subject and one recording (CGS units).

    Defaults are the paper's Table 2 constants and its male fold (Table 3). The subglottal
    pressure is not given in the paper; `MODEL_SPEC.md` infers it (11 250 dyne/cm² for the
    male sets N1, N2; 3 500 dyne/cm² for the female sets N3, N4).

    Arguments:
        mass: mass of one vocal fold, M (g).
        length: vocal-fold length, l (cm).
        thickness: vocal-fold thickness, d (cm).
        rest_area: glottal area at the equilibrium position x = 0, A_g0 (cm²).
        subglottal_pressure: lung-driven pressure below the glottis, P_s (dyne/cm²).
        air_density: rho (g/cm³).
        air_viscosity: dynamic viscosity mu (poise).
    """

    mass: ArrayLike = eqx.field(default=0.12, converter=as_parameter)
    length: ArrayLike = eqx.field(default=1.6, converter=as_parameter)
    thickness: ArrayLike = eqx.field(default=0.32, converter=as_parameter)
    rest_area: ArrayLike = eqx.field(default=0.05, converter=as_parameter)
    subglottal_pressure: ArrayLike = eqx.field(default=11250.0, converter=as_parameter)
    air_density: ArrayLike = eqx.field(default=1.3e-3, converter=as_parameter)
    air_viscosity: ArrayLike = eqx.field(default=1.8e-4, converter=as_parameter)

    constraints: ClassVar = (
        positive("mass", "M (mass)", "g"),
        positive("length", "l (length)", "cm"),
        positive("thickness", "d (thickness)", "cm"),
        positive("rest_area", "A_g0 (rest_area)", "cm²"),
        positive("subglottal_pressure", "P_s (subglottal_pressure)", "dyne/cm²"),
        positive("air_density", "air_density", "g/cm³"),
        positive("air_viscosity", "air_viscosity", "poise"),
    )

    def __check_init__(self):
        check_constraints(self)

    def is_valid(self):
        """Whether every constant is admissible (a traced boolean)."""
        return constraints_hold(self)

    @property
    def contact_displacement(self):
        """x_0 (cm): the displacement at which the folds meet and the area is zero (eq. 5)."""
        return -jnp.asarray(self.rest_area) / (2.0 * jnp.asarray(self.length))

    def area(self, x):
        """Glottal area A_g = A_g0 + 2 l x (cm²) for displacement ``x`` (cm), eq. 4."""
        return self.rest_area + 2.0 * self.length * x
