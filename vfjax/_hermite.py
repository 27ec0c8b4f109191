"""Cubic Hermite interpolation on one step, and its root with implicit derivatives."""

import jax
import jax.numpy as jnp


def hermite(theta, y0, d0, y1, d1):
    """Cubic through (0, y0) and (1, y1) with slopes d0, d1 (per unit theta)."""
    t2 = theta * theta
    t3 = t2 * theta
    return (
        (2 * t3 - 3 * t2 + 1) * y0
        + (t3 - 2 * t2 + theta) * d0
        + (-2 * t3 + 3 * t2) * y1
        + (t3 - t2) * d1
    )


def hermite_slope(theta, y0, d0, y1, d1):
    """d/dtheta of `hermite`."""
    t2 = theta * theta
    return (6 * t2 - 6 * theta) * (y0 - y1) + (3 * t2 - 4 * theta + 1) * d0 + (3 * t2 - 2 * theta) * d1


def _safe_div(num, den, tiny=1e-300):
    ok = jnp.abs(den) > tiny
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def hermite_root(y0, d0, y1, d1, target, iterations: int = 8):
    """First-found root in [0, 1] of ``hermite(theta) = target``, assuming a sign change.

    The bracketed Newton iterations run on stopped gradients; one final Newton step on the
    live coefficients gives the root the derivative of the implicit function theorem,
    d(theta)/dp = -(dg/dp) / (dg/dtheta). This is what makes event times differentiable.
    """
    c = jax.lax.stop_gradient((y0 - target, d0, y1 - target, d1))
    g0, g1 = c[0], c[2]
    theta = jnp.clip(_safe_div(g0, g0 - g1), 0.0, 1.0)
    lo, hi = jnp.zeros_like(theta), jnp.ones_like(theta)
    for _ in range(iterations):
        g = hermite(theta, *c)
        same = jnp.sign(g) == jnp.sign(g0)
        lo = jnp.where(same, theta, lo)
        hi = jnp.where(same, hi, theta)
        step = theta - _safe_div(g, hermite_slope(theta, *c))
        inside = (step > lo) & (step < hi)
        theta = jnp.where(g == 0, theta, jnp.where(inside, step, 0.5 * (lo + hi)))
    theta = jax.lax.stop_gradient(theta)
    live = (y0 - target, d0, y1 - target, d1)
    slope = hermite_slope(theta, *live)
    return jnp.clip(theta - _safe_div(hermite(theta, *live), slope), 0.0, 1.0)
