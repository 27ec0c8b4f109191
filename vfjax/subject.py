"""The subject's constants: vocal-fold geometry, mass, and the air that drives it."""

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import ArrayLike

from ._validate import as_float, check_positive


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

    mass: ArrayLike = eqx.field(default=0.12, converter=as_float)
    length: ArrayLike = eqx.field(default=1.6, converter=as_float)
    thickness: ArrayLike = eqx.field(default=0.32, converter=as_float)
    rest_area: ArrayLike = eqx.field(default=0.05, converter=as_float)
    subglottal_pressure: ArrayLike = eqx.field(default=11250.0, converter=as_float)
    air_density: ArrayLike = eqx.field(default=1.3e-3, converter=as_float)
    air_viscosity: ArrayLike = eqx.field(default=1.8e-4, converter=as_float)

    def __check_init__(self):
        check_positive("mass", self.mass, "g")
        check_positive("length", self.length, "cm")
        check_positive("thickness", self.thickness, "cm")
        check_positive("rest_area", self.rest_area, "cm²")
        check_positive("subglottal_pressure", self.subglottal_pressure, "dyne/cm²")
        check_positive("air_density", self.air_density, "g/cm³")
        check_positive("air_viscosity", self.air_viscosity, "poise")

    @property
    def contact_displacement(self):
        """x_0 (cm): the displacement at which the folds meet and the area is zero (eq. 5)."""
        return -jnp.asarray(self.rest_area) / (2.0 * jnp.asarray(self.length))

    def area(self, x):
        """Glottal area A_g = A_g0 + 2 l x (cm²) for displacement ``x`` (cm), eq. 4."""
        return self.rest_area + 2.0 * self.length * x
