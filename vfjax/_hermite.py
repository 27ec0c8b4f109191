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


def _safe_div(num, den):
    # below `tiny` the quotient counts as undefined (1e-300 in double precision; the swarm's
    # single-precision integrations, `integrate_window_single`, use 1e-30)
    tiny = 1e-300 if jnp.result_type(den) == jnp.float64 else 1e-30
    ok = jnp.abs(den) > tiny
    return jnp.where(ok, num / jnp.where(ok, den, 1.0), 0.0)


def _poly(c, theta):
    return c[0] + theta * (c[1] + theta * (c[2] + theta * c[3]))


def _poly_slope(c, theta):
    return c[1] + theta * (2.0 * c[2] + theta * 3.0 * c[3])


def hermite_root(y0, d0, y1, d1, target, iterations: int = 6):
    """Root in [0, 1] of ``hermite(theta) = target``, given a sign change over [0, 1].

    Arguments may carry a leading axis to solve several independent problems at once
    (`hermite_roots` solves problems given apart, without stacking them).

    When the step starts exactly on the surface (a just-located event), the trivial root at
    theta = 0 is divided out, so a trajectory that moves off the surface and comes back within
    the step yields its return crossing, not a zero-length event at the start.

    Safeguarded Newton from the secant guess (its square root for a step that starts at
    rest) runs on stopped gradients; one final Newton step on the live coefficients gives
    the root the derivative of the implicit function theorem, d(theta)/dp = -(dg/dp) /
    (dg/dtheta). This is what makes event times differentiable, exactly so only where the
    stopped iterations have converged: then the derivative is that of the computed root. On
    a step of the integrator the cubic is usually close to linear and the secant guess is
    accurate to O(dt²), but at a grazing contact (the paper's N1 and N3 close with
    0.001-0.03 mm² of overlap) it is far from linear: four iterations leave d GAW / d C_f at
    N3 0.9 % off converged central differences, six bring every parameter at N1-N4, and at
    folds leaving a hold at rest, to 1e-6 (`tests/test_derivatives.py`), for about 10 % of
    the simulator's time at batch 64. A convergence test (a while loop) costs more than it
    saves: under `vmap` it runs for the slowest member at every step.
    """
    (root,) = hermite_roots((y0, d0, y1, d1, target), iterations=iterations)
    return root


def hermite_roots(*problems, iterations: int = 6, unrolled: bool = False):
    """`hermite_root` of each of ``problems`` (tuples ``(y0, d0, y1, d1, target)``), solved
    side by side in one Newton loop; returns a tuple of roots.

    The problems stay separate arrays rather than one stacked array: in a loop's body on a
    CPU, XLA runs kernels one after another only while each array they touch is small (see
    `vfjax._integrate._events._alone`), and a stack of two doubles it.

    ``unrolled``: the Newton iterations as straight-line code rather than a loop, for a
    caller that materialises each root once (`vfjax._integrate._events._computed_once`).
    XLA then fuses each root's iterations into one kernel, where the loop runs seven kernels
    an iteration (the single-precision swarm's iteration: 50 kernels rather than about 120,
    and a quarter less time for 48 particles). In the chunked loop the consumers of a
    stacked root each copy the unrolled iterations: four times slower there."""
    setups = [_newton_setup(*problem) for problem in problems]

    def newton(_, states):
        return tuple(_newton_step(setup, state) for setup, state in zip(setups, states))

    # A loop unless ``unrolled``: XLA's CPU fusion copies unrolled iterations into every
    # consumer of a root that is not materialised once (several times slower in the chunked
    # integrator).
    start = tuple(
        (theta, jnp.zeros_like(theta), jnp.ones_like(theta)) for _, _, _, theta, _ in setups
    )
    if unrolled:
        states = start
        for i in range(iterations):
            states = newton(i, states)
    else:
        states = jax.lax.fori_loop(0, iterations, newton, start)
    return tuple(_newton_finish(setup, state) for setup, state in zip(setups, states))


def _newton_setup(y0, d0, y1, d1, target):
    """The cubic's live and stopped coefficients, its deflated form and the first guess."""
    g0 = y0 - target
    live = (g0, d0, 3.0 * (y1 - y0) - 2.0 * d0 - d1, 2.0 * (y0 - y1) + d0 + d1)
    c = jax.lax.stop_gradient(live)
    on_surface = c[0] == 0
    # Deflated polynomial (g / theta) when g(0) = 0; the cubic itself otherwise.
    p = [jnp.where(on_surface, b, a) for a, b in zip(c, (c[1], c[2], c[3], 0.0 * c[3]))]
    p_lo, p_hi = p[0], p[0] + p[1] + p[2] + p[3]
    # No sign change of the deflated polynomial: the trajectory leaves at theta = 0.
    immediate = on_surface & (jnp.sign(p_lo) == jnp.sign(p_hi))
    theta = jnp.clip(_safe_div(p_lo, p_lo - p_hi), 0.0, 1.0)
    # A step that starts at rest (a closure hold's release: v = 0) leaves the surface
    # quadratically, g ~ g(0) + (g(1) - g(0)) theta², so its crossing lies near the square
    # root of the secant's; from the secant's own (far too early when g(0) is small) Newton
    # would first halve its distance to the root for several iterations.
    theta = jnp.where(p[1] == 0, jnp.sqrt(theta), theta)
    return live, p, p_lo, theta, immediate


def _newton_step(setup, state):
    """One Newton step inside the bracket [lo, hi]; a step that leaves it is replaced by
    bisection."""
    _, p, p_lo, _, _ = setup
    theta, lo, hi = state
    g = _poly(p, theta)
    same = jnp.sign(g) == jnp.sign(p_lo)
    lo = jnp.where(same, theta, lo)
    hi = jnp.where(same, hi, theta)
    step = theta - _safe_div(g, _poly_slope(p, theta))
    inside = (step >= lo) & (step <= hi)
    theta = jnp.where(g == 0, theta, jnp.where(inside, step, 0.5 * (lo + hi)))
    return theta, lo, hi


def _newton_finish(setup, state):
    """The root: the stopped iterations' result and one live Newton step (the derivative)."""
    live, _, _, _, immediate = setup
    theta = jax.lax.stop_gradient(jnp.where(immediate, 0.0, state[0]))
    step = theta - _safe_div(_poly(live, theta), _poly_slope(live, theta))
    return jnp.clip(jnp.where(theta > 0, step, theta), 0.0, 1.0)
