"""Particle swarm optimisation with the whole swarm evaluated as one batched call.

The swarm's cost function takes a (particles, dims) array and returns (particles,) costs, so a
vmapped simulator evaluates every particle in one call per iteration. Iterations run in
compiled chunks of fixed length whose number of live iterations is data, so that any
iteration count runs through one program, with progress reported between chunks.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

from ._options import Swarm


class SwarmState(NamedTuple):
    """Positions, velocities and bests of a swarm (all in the search space)."""

    position: Array  # (n, d)
    velocity: Array  # (n, d)
    best_position: Array  # (n, d) personal bests
    best_cost: Array  # (n,)
    global_position: Array  # (d,)
    global_cost: Array  # ()
    key: Array


def _finite_or_inf(cost):
    return jnp.where(jnp.isfinite(cost), cost, jnp.inf)


def init_swarm(cost_fn, lower, upper, n_particles: int, key, start=None) -> SwarmState:
    """A swarm spread over the box [lower, upper] by Latin-hypercube sampling, at rest.

    ``start`` (d,), if given, becomes particle 0 (clipped into the box).
    """
    d = lower.shape[0]
    k_perm, k_jit, key = jax.random.split(key, 3)
    perms = jax.vmap(lambda k: jax.random.permutation(k, n_particles))(
        jax.random.split(k_perm, d)
    ).T
    u = (perms + jax.random.uniform(k_jit, (n_particles, d))) / n_particles
    position = lower + u * (upper - lower)
    if start is not None:
        position = position.at[0].set(jnp.clip(start, lower, upper))
    cost = _finite_or_inf(cost_fn(position))
    i = jnp.argmin(cost)
    return SwarmState(
        position=position,
        velocity=jnp.zeros_like(position),
        best_position=position,
        best_cost=cost,
        global_position=position[i],
        global_cost=cost[i],
        key=key,
    )


def swarm_step(cost_fn, lower, upper, settings: Swarm, state: SwarmState) -> SwarmState:
    """One PSO iteration: move every particle, evaluate the swarm in one call, update bests."""
    key, k1, k2 = jax.random.split(state.key, 3)
    shape = state.position.shape
    r1, r2 = jax.random.uniform(k1, shape), jax.random.uniform(k2, shape)
    span = upper - lower
    v = (
        settings.inertia * state.velocity
        + settings.cognitive * r1 * (state.best_position - state.position)
        + settings.social * r2 * (state.global_position - state.position)
    )
    v = jnp.clip(v, -settings.max_speed * span, settings.max_speed * span)
    x = state.position + v
    if settings.boundary == "reflect":
        below, above = x < lower, x > upper
        x = jnp.where(below, 2 * lower - x, jnp.where(above, 2 * upper - x, x))
        v = jnp.where(below | above, -v, v)
    x = jnp.clip(x, lower, upper)
    cost = _finite_or_inf(cost_fn(x))
    better = cost < state.best_cost
    best_position = jnp.where(better[:, None], x, state.best_position)
    best_cost = jnp.where(better, cost, state.best_cost)
    i = jnp.argmin(best_cost)
    return SwarmState(x, v, best_position, best_cost, best_position[i], best_cost[i], key)


def run_chunk(cost_fn: Callable, lower, upper, settings: Swarm, state, live):
    """``settings.chunk`` iterations in one `lax.scan`, of which the first ``live`` (data)
    move the swarm and the rest leave it as it is; returns the state and the global best
    cost after each iteration."""

    def body(s, k):
        moved = swarm_step(cost_fn, lower, upper, settings, s)
        s = jax.tree.map(lambda a, b: jnp.where(k < live, a, b), moved, s)
        return s, s.global_cost

    return jax.lax.scan(body, state, jnp.arange(settings.chunk))
