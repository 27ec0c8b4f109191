"""Particle swarm optimisation of a batch of fits, every particle of every fit evaluated in
one batched call per iteration.

The per-swarm steps (`scatter`, `unvisited`, `settle`, `move`) act on one fit's swarm and are
vmapped over the batch; between them one cost call maps the positions of all swarms,
(fits, particles, dims), to their costs, so that a vmapped (and, on several devices,
sharded) simulator evaluates them at once. Iterations run in compiled chunks of fixed length
whose number of live iterations is data, so that any iteration count runs through one
program, with progress reported between chunks.
"""

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp
from jaxtyping import Array

from .._programs import returned
from ._options import Swarm


@returned
class SwarmState(NamedTuple):
    """Positions, velocities and bests of a swarm (all in the search space), with what the
    cost function found beside each best's cost (``aux``: for a fit, the rest of the
    polish's point, the profiled time shift and S)."""

    position: Array  # (n, d)
    velocity: Array  # (n, d)
    best_position: Array  # (n, d) personal bests
    best_cost: Array  # (n,)
    best_aux: Array  # (n, a)
    global_position: Array  # (d,)
    global_cost: Array  # ()
    global_aux: Array  # (a,)
    key: Array


def _finite_or_inf(cost):
    return jnp.where(jnp.isfinite(cost), cost, jnp.inf)


def scatter(lower, upper, n_particles: int, key, start=None):
    """Positions (n, d) spread over the box [lower, upper] by Latin-hypercube sampling, and
    the key left over. ``start`` (d,), if given, becomes particle 0 (clipped into the box)."""
    d = lower.shape[0]
    k_perm, k_jit, key = jax.random.split(key, 3)
    perms = jax.vmap(lambda k: jax.random.permutation(k, n_particles))(
        jax.random.split(k_perm, d)
    ).T
    u = (perms + jax.random.uniform(k_jit, (n_particles, d))) / n_particles
    position = lower + u * (upper - lower)
    if start is not None:
        position = position.at[0].set(jnp.clip(start, lower, upper))
    return position, key


def unvisited(position, key, n_aux: int = 0) -> SwarmState:
    """A swarm about to evaluate ``position`` (n, d), at rest: no particle has a cost yet
    (nor ``n_aux`` auxiliary values). Its first iteration (`run_chunk`) evaluates the
    positions and makes them the bests."""
    inf = jnp.full(position.shape[:1], jnp.inf, position.dtype)
    aux = jnp.zeros(position.shape[:1] + (n_aux,), position.dtype)
    return SwarmState(
        position=position,
        velocity=jnp.zeros_like(position),
        best_position=position,
        best_cost=inf,
        best_aux=aux,
        global_position=position[0],
        global_cost=inf[0],
        global_aux=aux[0],
        key=key,
    )


def move(settings: Swarm, lower, upper, state: SwarmState):
    """One PSO move of every particle: the new positions, velocities and key."""
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
    return jnp.clip(x, lower, upper), v, key


def settle(state: SwarmState, cost, aux) -> SwarmState:
    """The swarm once its positions are evaluated (costs ``cost``, auxiliary values
    ``aux``): personal and global bests updated."""
    cost = _finite_or_inf(cost)
    better = cost < state.best_cost
    best_position = jnp.where(better[:, None], state.position, state.best_position)
    best_cost = jnp.where(better, cost, state.best_cost)
    best_aux = jnp.where(better[:, None], aux, state.best_aux)
    i = jnp.argmin(best_cost)
    return state._replace(
        best_position=best_position,
        best_cost=best_cost,
        best_aux=best_aux,
        global_position=best_position[i],
        global_cost=best_cost[i],
        global_aux=best_aux[i],
    )


def run_chunk(batch_cost: Callable, lowers, uppers, settings: Swarm, states, live):
    """``settings.chunk`` iterations of a batch of swarms in one `lax.scan`, of which the
    first ``live`` (data, one number for the batch) act and the rest leave the swarms as
    they are at no cost. An iteration evaluates every particle's position, updates the bests
    and moves the particles; a swarm's first iteration (from `unvisited`) evaluates its
    initial positions, so a search of N iterations is N + 1 evaluations, the last move
    unused.

    ``batch_cost`` maps the positions of every swarm, (fits, n, d), to their costs and
    auxiliary values, (fits, n) and (fits, n, a), in one call (one batched simulation of
    every particle of every fit). Returns the states and each swarm's best cost after each
    iteration, (fits, chunk)."""

    def iteration(s):
        evaluated = jax.vmap(settle)(s, *batch_cost(s.position))
        x, v, keys = jax.vmap(lambda lo, hi, st: move(settings, lo, hi, st))(
            lowers, uppers, evaluated
        )
        return evaluated._replace(position=x, velocity=v, key=keys)

    def body(s, k):
        # a scalar predicate: the chunk's idle iterations simulate nothing
        s = jax.lax.cond(k < live, iteration, lambda s: s, s)
        return s, s.global_cost

    states, costs = jax.lax.scan(body, states, jnp.arange(settings.chunk))
    return states, costs.T
