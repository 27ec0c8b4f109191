"""The local stage: an optimistix least-squares solve of the residual vector."""

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


@residual.defjvp
def _residual_jvp(primals, tangents):
    y, problem = primals
    dy, _ = tangents
    basis = jnp.eye(y.shape[0], dtype=y.dtype)
    r, jac = jax.vmap(lambda t: jax.jvp(problem.residual, (y,), (t,)), out_axes=(None, 1))(basis)
    return r, jac @ dy


def cost(problem: Problem, y):
    """The NMSE at ``y``."""
    return jnp.sum(problem.residual(y) ** 2)


def polish(problem: Problem, y0, options: Polish):
    """The best point the solver finds from ``y0``, its NMSE, the steps taken and the
    solver's result code (one problem; the engine vmaps it over a batch)."""
    solver = optx.BestSoFarLeastSquares(options.solver)
    sol = optx.least_squares(
        residual,
        solver,
        y0,
        args=problem,
        options={"jac": "fwd"},
        max_steps=options.max_steps,
        throw=False,
    )
    y = sol.value
    c0, c = cost(problem, y0), cost(problem, y)
    # the best-so-far wrapper returns the best point it saw, y0 included
    better = jnp.isfinite(c) & (c <= c0)
    return jnp.where(better, y, y0), jnp.where(better, c, c0), sol.stats["num_steps"], sol.result
