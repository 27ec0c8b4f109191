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
    return (
        (6 * t2 - 6 * theta) * (y0 - y1) + (3 * t2 - 4 * theta + 1) * d0 + (3 * t2 - 2 * theta) * d1
    )


def _safe_div(num, den, tiny=1e-300):
    ok = jnp.abs(den) > tiny
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def _poly(c, theta):
    return c[0] + theta * (c[1] + theta * (c[2] + theta * c[3]))


def _poly_slope(c, theta):
    return c[1] + theta * (2.0 * c[2] + theta * 3.0 * c[3])


def _quadratic_guess(g0, slope0, g1):
    """The root in [0, 1] of the quadratic with value ``g0`` and slope ``slope0`` at 0 and
    value ``g1`` at 1 (opposite in sign to ``g0``); the secant root where it has none.

    A step that starts at rest (a closure hold's release: v = 0) leaves the surface
    quadratically, g ~ g0 + a theta², and its crossing lies near sqrt(-g0 / a), far from
    the secant root when g0 is small: Newton from there first halves its distance to the
    root for several iterations. The quadratic puts it within O(theta³) of the root."""
    secant = jnp.clip(_safe_div(g0, g0 - g1), 0.0, 1.0)
    a = g1 - g0 - slope0
    disc = slope0 * slope0 - 4.0 * a * g0
    ok = disc >= 0
    s = jnp.sqrt(jnp.where(ok, disc, 0.0))
    q = -0.5 * (slope0 + jnp.where(slope0 >= 0, s, -s))
    # the two roots are q / a and g0 / q (cancellation-free); keep the one in [0, 1]
    first = _safe_div(q, a)
    second = _safe_div(g0, q)
    inside = (second >= 0) & (second <= 1) & (q != 0)
    root = jnp.where(inside, second, first)
    good = ok & (root >= 0) & (root <= 1) & (jnp.where(inside, q, a) != 0)
    return jnp.where(good, root, secant)


def hermite_root(y0, d0, y1, d1, target, iterations: int = 4):
    """Root in [0, 1] of ``hermite(theta) = target``, given a sign change over [0, 1].

    Arguments may carry a leading axis to solve several independent problems at once.

    When the step starts exactly on the surface (a just-located event), the trivial root at
    theta = 0 is divided out, so a trajectory that moves off the surface and comes back within
    the step yields its return crossing, not a zero-length event at the start.

    Safeguarded Newton (bisection where a step leaves the bracket) from the root of the
    quadratic through g(0), g'(0) and g(1) runs on stopped gradients; one final Newton step
    on the live coefficients gives the root the derivative of the implicit function
    theorem, d(theta)/dp = -(dg/dp) / (dg/dtheta). This is what makes event times
    differentiable, exactly so only where the stopped iterations have converged: then the
    derivative is that of the computed root. At a grazing contact (the paper's N1 and N3
    close with 0.001-0.03 mm² of overlap) and where a hold releases the folds at rest, the
    cubic is far from linear; from the quadratic's root four iterations bring d GAW / dp at
    N1-N4 and at a hold release to converged central differences within 1e-6
    (`tests/test_derivatives.py`). A convergence test (a while loop) costs more than it
    saves: under `vmap` it runs for the slowest member at every step.
    """
    g0 = y0 - target
    live = (g0, d0, 3.0 * (y1 - y0) - 2.0 * d0 - d1, 2.0 * (y0 - y1) + d0 + d1)
    c = jax.lax.stop_gradient(live)
    on_surface = c[0] == 0
    # Deflated polynomial (g / theta) when g(0) = 0; the cubic itself otherwise.
    p = [jnp.where(on_surface, b, a) for a, b in zip(c, (c[1], c[2], c[3], 0.0 * c[3]))]
    p_lo, p_hi = p[0], p[0] + p[1] + p[2] + p[3]
    # No sign change of the deflated polynomial: the trajectory leaves at theta = 0.
    immediate = on_surface & (jnp.sign(p_lo) == jnp.sign(p_hi))
    theta = _quadratic_guess(p_lo, p[1], p_hi)

    def newton(_, state):
        # Newton inside the bracket [lo, hi]; a step that leaves it is replaced by bisection.
        theta, lo, hi = state
        g = _poly(p, theta)
        same = jnp.sign(g) == jnp.sign(p_lo)
        lo = jnp.where(same, theta, lo)
        hi = jnp.where(same, hi, theta)
        step = theta - _safe_div(g, _poly_slope(p, theta))
        inside = (step >= lo) & (step <= hi)
        theta = jnp.where(g == 0, theta, jnp.where(inside, step, 0.5 * (lo + hi)))
        return theta, lo, hi

    # A loop, not unrolled Python: XLA's CPU fusion would otherwise copy the iterations into
    # every consumer of the root (several times slower in the integrator).
    theta, _, _ = jax.lax.fori_loop(
        0, iterations, newton, (theta, jnp.zeros_like(theta), jnp.ones_like(theta))
    )
    theta = jax.lax.stop_gradient(jnp.where(immediate, 0.0, theta))
    step = theta - _safe_div(_poly(live, theta), _poly_slope(live, theta))
    return jnp.clip(jnp.where(theta > 0, step, theta), 0.0, 1.0)
