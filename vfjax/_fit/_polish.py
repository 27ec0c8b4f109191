"""The local stage: an optimistix least-squares solve of the residual vector."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from .._batching import batched_like
from ._options import Polish
from ._problem import Problem


@jax.custom_jvp
def residual(y, problem: Problem):
    """`Problem.residual`, whose linearisation is its Jacobian matrix.

    optimistix linearises the residual function at every step and keeps the linearisation in
    its state. Through the simulator that keeps every intermediate of the integration: slow
    to compile and to carry. This rule computes the Jacobian's columns at once
    (`Problem.residual_and_jacobian`: forward mode, one batched jvp) and returns J @ dy, so
    the linearisation is one (frames, params) matrix.
    Differentiates in ``y`` only (the solver's variable)."""
    return problem.residual(y)


def jacobian_columns(fn, y, basis):
    """``fn(y)`` and its derivatives along the rows of ``basis`` as columns (one batched
    forward-mode jvp): (residual, (len(residual), len(basis)))."""
    return jax.vmap(lambda t: jax.jvp(fn, (y,), (t,)), out_axes=(None, 1))(basis)


#: Each step's trial dampings, as multiples of the current one (five decades apart): near a
#: grazing closure, where one more or one fewer cycle reaches contact, a Gauss-Newton step is
#: good only within a small region, and one trial per step can spend every step shrinking
#: towards it; each trial costs a simulation beside the step's Jacobian.
_DAMPING_TRIALS = (1e-4, 1e1)
_DAMPING_START = 1.0  # the first step tries 1e-4 and 10
_DAMPING_RISE = 1e4  # after a step that no trial improves


def levenberg_marquardt(residual, y0, basis, steps: int, jacobian=None, jacobian_every: int = 1):
    """``steps`` Levenberg-Marquardt steps on ``residual`` from ``y0`` within the span of the
    rows of ``basis`` (unit vectors of the free coordinates; zero rows are ignored), keeping
    the best point: (point, its sum of squares). ``jacobian``: a function of a point and
    the basis that returns the residual there and its derivatives along the rows as
    columns (such as `Problem.residual_and_jacobian`); by default `jacobian_columns` of
    ``residual``. ``jacobian_every``: the Jacobian is computed at the first step and at
    every ``jacobian_every``-th after it; the steps between update it by Broyden's rank-one
    secant rule from each trial's residual (1: a Jacobian at every step).

    The best is kept over every evaluation, the Jacobian's residual at each step's point
    included: near a grazing closure the model is discontinuous, and the same point can
    cost one value in a trial and another where the next step re-evaluates it with its
    Jacobian (rounding decides whether a hold starts), so the last accepted point's cost
    alone can lie far above the start's (a null recording of the shared syn_gap's fit:
    0.73 against 0.0005).

    A fixed number of steps (a `lax.scan`), so that a batch of refits runs in lock step and the
    solve traces inside any vmap. Each step: the Jacobian's columns by forward mode (one batched
    jvp, which also gives the residual) or their secant update, and damped Gauss-Newton steps
    with Marquardt's scaling at two dampings five decades apart about the current one
    (`_DAMPING_TRIALS`: 1e-4 times it and 10 times it; the first step tries 1e-4 and 10),
    evaluated one after the other; the better one is taken if it improves, and its damping
    becomes the current one; if neither improves, the damping rises by `_DAMPING_RISE`. The
    Jacobian costs most of a step (a forward tangent through the integrator costs about twice
    the residual: six columns about seven residuals). The first step's damping of 10 steps
    short of a jump that a nearly undamped step crosses (a grazing closure: one more cycle
    reaching contact); the smaller trial, nearly Gauss-Newton, lets every step go far along a
    flat valley of the error.

    The trials run in a `lax.map`, one after the other: vmapped, they run no faster on a CPU
    (a batch of 16 recordings of the calibration's statistic on the shared syn_gap's first
    fit, 2 CPU devices, 2026-12-02: 8.3-8.4 s in a `lax.map`, 8.4-8.7 s vmapped) and round
    otherwise (that batch's refit errors moved by up to 8 %)."""

    if steps < 1:
        c0 = jnp.sum(residual(y0) ** 2)
        return y0, jnp.where(jnp.isfinite(c0), c0, jnp.inf)
    if jacobian_every < 1:
        raise ValueError(f"jacobian_every must be >= 1, got {jacobian_every}")
    ratios = jnp.asarray(_DAMPING_TRIALS, y0.dtype)
    if jacobian is None:

        def jacobian(y, basis):
            return jacobian_columns(residual, y, basis)

    def finite(cost):
        return jnp.where(jnp.isfinite(cost), cost, jnp.inf)

    def step(carry, index):
        y, r, j, damping, y_best, c_best = carry
        if jacobian_every > 1:
            # the step index is the same for every member of a batch: a real branch under vmap
            r, j = jax.lax.cond(
                index % jacobian_every == 0, lambda: jacobian(y, basis), lambda: (r, j)
            )
        else:
            r, j = jacobian(y, basis)
        c = finite(jnp.sum(r**2))
        y_best, c_best = _better((y, c), (y_best, c_best))
        h = j.T @ j
        g = j.T @ r
        d = jnp.diag(h)
        d = jnp.where(d > 0, d, 1.0)  # a zero column (a padding direction) does not move

        def trial(level):
            move = -jnp.linalg.solve(h + level * jnp.diag(d), g)
            point = y + basis.T @ move
            moved = residual(point)
            return point, move, moved, finite(jnp.sum(moved**2))

        levels = damping * ratios
        points, moves, moved, costs = jax.lax.map(trial, levels)  # see the docstring
        if jacobian_every > 1:
            # Broyden's secant update from each trial (the model is smooth between its
            # switches; a trial across one can spoil the update until the next Jacobian,
            # never the best point kept)
            for k in range(len(_DAMPING_TRIALS)):
                s = moves[k]
                ss = jnp.sum(s**2)
                ok = jnp.isfinite(costs[k]) & (ss > 0)
                update = jnp.outer(moved[k] - r - j @ s, s) / jnp.where(ok, ss, 1.0)
                j = jnp.where(ok, j + update, j)
        best = jnp.argmin(costs)
        better = costs[best] < c
        y = jnp.where(better, points[best], y)
        r = jnp.where(better, moved[best], r)
        c = jnp.where(better, costs[best], c)
        y_best, c_best = _better((y, c), (y_best, c_best))
        damping = jnp.clip(jnp.where(better, levels[best], damping * _DAMPING_RISE), 1e-12, 1e12)
        return (y, r, j, damping, y_best, c_best), None

    r0, j0 = jax.eval_shape(jacobian, y0, basis)
    init = (
        y0,
        jnp.zeros(r0.shape, r0.dtype),
        jnp.zeros(j0.shape, j0.dtype),
        jnp.asarray(_DAMPING_START, y0.dtype),
        y0,
        jnp.asarray(jnp.inf, y0.dtype),
    )
    # batched from the first trace under vmap wherever the start is (see `batched_like`)
    init = batched_like(y0, init)
    (*_, y, c), _ = jax.lax.scan(step, init, jnp.arange(steps))
    return y, c


def _better(new, old):
    """The (point, cost) pair of lower cost (``old`` on a tie)."""
    take = new[1] < old[1]
    return jnp.where(take, new[0], old[0]), jnp.where(take, new[1], old[1])


@eqx.filter_jit
def _residual_and_jacobian(y, problem: Problem):
    # a nested program: optimistix traces the linearisation more than once per solve, and
    # each trace then reuses this one
    return problem.residual_and_jacobian(y, jnp.eye(y.shape[0], dtype=y.dtype))


@residual.defjvp
def _residual_jvp(primals, tangents):
    y, problem = primals
    dy, _ = tangents
    r, jac = _residual_and_jacobian(y, problem)
    return r, jac @ dy


def _with_cost(y, problem: Problem):
    r = residual(y, problem)
    return r, jnp.sum(jax.lax.stop_gradient(r) ** 2)


#: optimistix's result codes that a polish reports, by their index in `polish`'s output
#: (any other is "unknown").
RESULT_NAMES = (
    "successful",
    "nonlinear_max_steps_reached",
    "nonlinear_divergence",
    "singular",
    "breakdown",
    "stagnation",
    "nonfinite",
)


def result_index(result) -> jax.Array:
    """The index in `RESULT_NAMES` of an `optimistix.RESULTS` item (traced), or its length
    for a code not among them: a plain integer array, which a stored program returns
    (`vfjax._programs`)."""
    members = [getattr(optx.RESULTS, n, None) for n in RESULT_NAMES]
    index = jnp.asarray(len(RESULT_NAMES), jnp.int32)
    for i, member in reversed(list(enumerate(members))):
        if member is not None:
            index = jnp.where(result == member, i, index)
    return index


def polish(problem: Problem, y0, cost0, options: Polish):
    """The best point the solver finds from ``y0`` (whose NMSE is ``cost0``), its NMSE, the
    steps taken and the solver's result (its index in `RESULT_NAMES`, `result_index`; one
    problem; the engine vmaps it)."""
    sol = optx.least_squares(
        _with_cost,
        optx.BestSoFarLeastSquares(options.solver),
        y0,
        args=problem,
        options={"jac": "fwd"},
        has_aux=True,
        max_steps=options.max_steps,
        throw=False,
    )
    # the best point seen (the start included), with its NMSE as the auxiliary output
    better = jnp.isfinite(sol.aux) & (sol.aux <= cost0)
    y = jnp.where(better, sol.value, y0)
    return y, jnp.where(better, sol.aux, cost0), sol.stats["num_steps"], result_index(sol.result)
