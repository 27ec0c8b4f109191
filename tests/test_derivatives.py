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
#: between closing and not closing (N1 closes with 0.001 mm² of overlap: a 0.1 % rise of C_f
#: opens it, `test_n1_sits_within_a_tenth_of_a_percent_of_the_closing_boundary`), and FD
#: across that boundary measures a different regime; near it the GAW curves sharply (a grazing
#: contact), so FD converges only below ~1e-5. At 1e-6 its error is ~1e-7 (~ step²).
FD_STEP = 1e-6
#: The derivatives are those of the computed GAW itself: forward mode agrees with converged
#: central differences to the differences' own accuracy (worst 5e-7 at N1-N4).
JAC_TOL = 1e-4


def _gaw(model, rel):
    """GAW (px) with each parameter in NAMES scaled by (1 + rel[i])."""
    p = model.params()
    return vfjax.simulate(
        model.set(**{n: p[n] * (1.0 + rel[i]) for i, n in enumerate(NAMES)}),
        FPS,
        N_FRAMES,
        throw=False,
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
        assert err < JAC_TOL, f"{name}: d GAW / d {param} off by {100 * err:.2g} %"


@eqx.filter_jit
def _loss_gradient_and_fd(model, target):
    """jax.grad of the fit's NMSE (GAW clipped at zero, as a camera sees it) in the relative
    parameters, and its central differences."""

    def loss(rel):
        g = jnp.maximum(_gaw(model, rel), 0.0)
        return jnp.sum((g - target) ** 2) / jnp.sum(target**2)

    zero = jnp.zeros(len(NAMES))
    steps = jnp.concatenate([jnp.eye(len(NAMES)), -jnp.eye(len(NAMES))]) * FD_STEP
    runs = jax.vmap(loss)(steps)
    return jax.grad(loss)(zero), (runs[: len(NAMES)] - runs[len(NAMES) :]) / (2 * FD_STEP)


@pytest.mark.parametrize("name", ["N1", "N2", "N3", "N4"])
def test_loss_gradient_matches_central_differences(name):
    """Reverse mode through the whole loss (the 201-frame GAW of the set, against the same GAW
    with 2 px of seeded noise) equals converged central differences to 1e-4 of its size."""
    model = vfjax.preset(name)
    clean = np.clip(np.asarray(_gaw(model, jnp.zeros(len(NAMES)))), 0.0, None)
    target = clean + np.random.default_rng(3).normal(0.0, 2.0, clean.size)
    grad, fd = _loss_gradient_and_fd(model, jnp.asarray(target))
    grad, fd = np.asarray(grad), np.asarray(fd)
    scale = np.linalg.norm(fd)
    for i, param in enumerate(NAMES):
        err = abs(grad[i] - fd[i]) / max(abs(fd[i]), 1e-3 * scale)
        assert err < JAC_TOL, f"{name}: d loss / d {param} off by {100 * err:.2g} %"


def test_derivatives_exact_where_the_folds_leave_a_hold_at_rest():
    """A hold releases the folds at rest just inside contact (v = 0, 1e-7 cm deep): the step
    after it leaves the surface quadratically, the hardest case for the event root. A
    fitted N4-based model of a demo recording (K and C_f as a fit left them) releases so
    in every cycle; forward mode must still equal converged central differences (an
    unconverged root left d GAW / d C_f 7 % off here)."""
    model = vfjax.preset("N4").set(K=829019.2, C_f=453.989, t_c=0.00295461, S=1.0)
    params = model.params()

    def gaw(rel):
        changed = model.set(K=params["K"] * (1 + rel[0]), C_f=params["C_f"] * (1 + rel[1]))
        return vfjax.simulate(
            changed, FPS, N_FRAMES, t_start=0.02, time_shift=0.007625, max_time_shift=0.01
        ).area

    zero = jnp.zeros(2)
    jac = np.asarray(jax.jit(jax.jacfwd(gaw))(zero))
    run = jax.jit(gaw)
    for i, param in enumerate(("K", "C_f")):
        step = FD_STEP * np.eye(2)[i]
        fd = (np.asarray(run(step)) - np.asarray(run(-step))) / (2 * FD_STEP)
        err = np.linalg.norm(jac[:, i] - fd) / np.linalg.norm(fd)
        assert err < JAC_TOL, f"d GAW / d {param} off by {100 * err:.2g} %"
    closed = vfjax.simulate(model, FPS, N_FRAMES, t_start=0.02).phase == vfjax.phases.CLOSED
    assert int(jnp.sum(closed)) > 20, "the case must close (and so release from holds)"


def test_n1_sits_within_a_tenth_of_a_percent_of_the_closing_boundary():
    """Why finite differences need steps far below 0.1 %: N1 closes (132 closed frames) and
    with C_f 0.1 % higher never does. Across that boundary the GAW (and a loss) jumps, so a
    difference quotient over it measures the jump, not a derivative."""
    model = vfjax.preset("N1")
    c_f = float(model.params()["C_f"])

    def closed_frames(factor):
        sim = vfjax.simulate(model.set(C_f=c_f * factor), FPS, N_FRAMES, t_start=0.03)
        return int(jnp.sum(sim.phase == vfjax.phases.CLOSED))

    assert closed_frames(1.0) > 100 and closed_frames(1.0003) > 100
    assert closed_frames(1.001) == 0


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
    corners = np.array(
        [
            [0.2, 0.2, 1.0, 1.0, 1.0],
            [1.8, 1.8, 1.0, 1.0, 1.0],
            [0.2, 1.8, 0.2, 0.2, 1.8],
            [1.8, 0.2, 1.8, 1.8, 0.2],
        ]
    )
    return jnp.asarray(np.concatenate([pts, corners]) - 1.0)


@eqx.filter_jit
def _box_gradients(model, rel_points):
    target = _gaw(model, jnp.zeros(len(NAMES)))

    def cost(rel):
        sim = _gaw(model, rel)
        return jnp.sum((sim - target) ** 2) / jnp.sum(target**2)

    def one(rel):
        value, grad = jax.value_and_grad(cost)(rel)
        sim = vfjax.simulate(model, FPS, N_FRAMES, throw=False)  # the point's own regime
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
