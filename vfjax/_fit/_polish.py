"""The local stage: an optimistix least-squares solve of the residual vector."""

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx

from ._options import Polish
from ._problem import Problem


@jax.custom_jvp
def residual(y, problem: Problem):
    """`Problem.residual`, whose linearisation is its Jacobian matrix.

    optimistix linearises the residual function at every step and keeps the linearisation in
    its state. Through the simulator that keeps every intermediate of the integration: slow
    to compile and to carry. This rule computes the Jacobian's columns at once (forward mode,
    one batched jvp) and returns J @ dy, so the linearisation is one (frames, params) matrix.
    Differentiates in ``y`` only (the solver's variable)."""
    return problem.residual(y)


def jacobian_columns(fn, y, basis):
    """``fn(y)`` and its derivatives along the rows of ``basis`` as columns (one batched
    forward-mode jvp): (residual, (len(residual), len(basis)))."""
    return jax.vmap(lambda t: jax.jvp(fn, (y,), (t,)), out_axes=(None, 1))(basis)


@eqx.filter_jit
def _residual_and_jacobian(y, problem: Problem):
    # a nested program: optimistix traces the linearisation more than once per solve, and
    # each trace then reuses this one
    return jacobian_columns(problem.residual, y, jnp.eye(y.shape[0], dtype=y.dtype))


@residual.defjvp
def _residual_jvp(primals, tangents):
    y, problem = primals
    dy, _ = tangents
    r, jac = _residual_and_jacobian(y, problem)
    return r, jac @ dy


def _with_cost(y, problem: Problem):
    r = residual(y, problem)
    return r, jnp.sum(jax.lax.stop_gradient(r) ** 2)


def polish(problem: Problem, y0, cost0, options: Polish):
    """The best point the solver finds from ``y0`` (whose NMSE is ``cost0``), its NMSE, the
    steps taken and the solver's result code (one problem; the engine vmaps it)."""
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
    return y, jnp.where(better, sol.aux, cost0), sol.stats["num_steps"], sol.result
