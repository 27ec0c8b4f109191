"""Loop carries batched from the start under `jax.vmap`, so that less is traced."""

import equinox as eqx
import jax
import jax.numpy as jnp


def batched_like(probe, tree):
    """``tree``'s values, batched under `jax.vmap` wherever ``probe`` (a pytree: a model, a
    state; its floating-point arrays are read) is.

    For the initial carry of a loop. `jax.vmap` batches a `lax.scan` or `lax.while_loop` by
    tracing its body with the carry batched as it enters, then again whenever the body makes
    a carry batched that entered unbatched (a counter or a row buffer that starts as a
    constant, a state that starts at zero), until nothing changes; each time, the loops
    inside the body are traced with it. A carry that starts from ``tree`` is batched from the
    first trace (the statistic of `vfjax.diagnose`, whose refits nest the integrator's loops
    in a Levenberg-Marquardt scan under two vmaps, is traced with a quarter fewer primitives
    batched and staged: benchmarks/README.md).

    Each leaf passes through a select of the leaf with itself, on a predicate computed from
    ``probe`` (whether its sum is finite): the same value whatever ``probe`` holds (NaN
    included), and no derivative added. XLA removes the selects of large arrays; what it
    keeps (a few scalars a member, and the sum) is computed once, before the loop, and the
    loop computes the same bits."""
    arrays = [jnp.sum(x, dtype=float) for x in jax.tree.leaves(probe) if eqx.is_inexact_array(x)]
    finite = jnp.isfinite(sum(arrays, jnp.zeros((), float)))
    return jax.tree.map(lambda leaf: jnp.where(finite, leaf, leaf), tree)
