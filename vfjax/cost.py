"""The fit cost.

The paper's eq. 23, ``sum(A_exp² - A_sim²) / sum(A_exp²)``, is not a distance: it is zero
whenever the two waveforms have the same energy and can be negative. vfjax uses the
normalised squared error, as `MODEL_SPEC.md` settles it.
"""

import jax.numpy as jnp


def nmse(measured, simulated):
    """Normalised mean squared error ``sum((measured - simulated)²) / sum(measured²)``."""
    measured = jnp.asarray(measured)
    return jnp.sum((measured - simulated) ** 2) / jnp.sum(measured**2)
