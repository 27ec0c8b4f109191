"""Derivatives of the 201-frame GAW: forward mode against central finite differences,
reverse mode against forward mode, and finite gradients across a wide parameter box."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vfjax

NAMES = ("K", "C_f", "S", "t_c", "P_s")
FPS, N_FRAMES = 4000.0, 201
#: Relative finite-difference step. Small, because the paper's sets sit close to the boundary
#: between closing and not closing (N1 closes with 0.001 mm² of overlap: a 0.03 % rise of C_f or
#: fall of P_s opens it), and FD across that boundary measures a different regime. The
#: simulated GAW is smooth down to far smaller steps (FD error ~ step², 1e-7 at 1e-6).
FD_STEP = 1e-5


def _gaw(model, rel):
    """GAW (px) with each parameter in NAMES scaled by (1 + rel[i])."""
    p = model.params()
    return vfjax.simulate(
        model.set(**{n: p[n] * (1.0 + rel[i]) for i, n in enumerate(NAMES)}), FPS, N_FRAMES
    ).area


@eqx.filter_jit
def _jacobian_and_fd(model):
    zero = jnp.zeros(len(NAMES))
    jac = jax.jacfwd(functools.partial(_gaw, model))(zero)  # (frames, params)
    steps = jnp.concatenate([jnp.eye(len(NAMES)), -jnp.eye(len(NAMES))]) * FD_STEP
    runs = jax.vmap(functools.partial(_gaw, model))(steps)
    fd = (runs[: len(NAMES)] - runs[len(NAMES) :]).T / (2 * FD_STEP)
    return jac, fd


@pytest.mark.parametrize("name", ["N1", "N2", "N3", "N4"])
def test_forward_mode_matches_central_differences(name):
    jac, fd = _jacobian_and_fd(vfjax.preset(name))
    for i, param in enumerate(NAMES):
        err = float(jnp.linalg.norm(jac[:, i] - fd[:, i]) / jnp.linalg.norm(fd[:, i]))
        assert err < 0.02, f"{name}: d GAW / d {param} off by {100 * err:.2f} %"


@eqx.filter_jit
def _forward_and_reverse(model, cotangent):
    zero = jnp.zeros(len(NAMES))
    f = functools.partial(_gaw, model)
    jac = jax.jacfwd(f)(zero)
    _, pullback = jax.vjp(f, zero)
    return cotangent @ jac, pullback(cotangent)[0]


def test_reverse_mode_matches_forward_mode():
    cotangent = jax.random.normal(jax.random.key(0), (N_FRAMES,))
    for name in ("N1", "N3"):
        fwd, rev = _forward_and_reverse(vfjax.preset(name), cotangent)
        np.testing.assert_allclose(rev, fwd, rtol=1e-8, atol=1e-8 * float(jnp.max(jnp.abs(fwd))))


def _box_points(n, seed):
    """Latin-hypercube points with every relative factor in [0.2, 1.8], plus the corners that
    give growing overlap (soft, weakly damped) and no closure (stiff, strongly damped)."""
    rng = np.random.default_rng(seed)
    u = (
        rng.permuted(np.tile(np.arange(n), (len(NAMES), 1)), axis=1).T + rng.random((n, len(NAMES)))
    ) / n
    pts = 0.2 + 1.6 * u
    corners = np.array([[0.2, 0.2, 1.0, 1.0, 1.0], [1.8, 1.8, 1.0, 1.0, 1.0],
                        [0.2, 1.8, 0.2, 0.2, 1.8], [1.8, 0.2, 1.8, 1.8, 0.2]])  # fmt: skip
    return jnp.asarray(np.concatenate([pts, corners]) - 1.0)


@eqx.filter_jit
def _box_gradients(model, rel_points):
    target = _gaw(model, jnp.zeros(len(NAMES)))

    def cost(rel):
        sim = _gaw(model, rel)
        return jnp.sum((sim - target) ** 2) / jnp.sum(target**2)

    def one(rel):
        value, grad = jax.value_and_grad(cost)(rel)
        sim = vfjax.simulate(model, FPS, N_FRAMES)  # for the regime of the point itself
        return value, grad, sim.complete

    values, grads, _ = jax.vmap(one)(rel_points)
    areas = jax.vmap(lambda r: _gaw(model, r))(rel_points)
    return values, grads, areas


@pytest.mark.parametrize("name", ["N1", "N3"])
def test_gradients_finite_across_the_box(name):
    model = vfjax.preset(name)
    values, grads, areas = _box_gradients(model, _box_points(20, seed=1))
    assert np.all(np.isfinite(np.asarray(values)))
    assert np.all(np.isfinite(np.asarray(grads))), "non-finite gradient in the ±80 % box"
    mins = np.asarray(jnp.min(areas[:, -80:], axis=1))
    assert np.any(mins > 1.0), "the box should include regimes that never close"
    assert np.any(mins < -5.0), "the box should include regimes with growing overlap"


@pytest.mark.slow
@pytest.mark.parametrize("name", ["N2", "N4"])
def test_gradients_finite_across_the_box_more(name):
    values, grads, _ = _box_gradients(vfjax.preset(name), _box_points(60, seed=2))
    assert np.all(np.isfinite(np.asarray(grads)))


def test_forward_only_simulation_refuses_reverse_mode():
    m = vfjax.preset("N3")

    def total(k, reverse_mode):
        return vfjax.simulate(m.set(K=k), FPS, N_FRAMES, reverse_mode=reverse_mode).area.sum()

    k = m.params()["K"]
    assert np.isfinite(float(jax.grad(total)(k, True)))
    with pytest.raises(ValueError, match="Reverse-mode differentiation does not work"):
        jax.grad(total)(k, False)
