"""The catalogue's effects against independent truths."""

import jax.numpy as jnp
import numpy as np
import pytest

import vfjax
from vfjax import (
    CubicStiffness,
    Elastic,
    GlottalGap,
    MucosalDelay,
    PressureModulation,
    Subject,
    VocalFoldModel,
)
from vfjax.datasets import demo_recording

FPS = 4000.0


def test_every_effect_at_its_off_value_changes_nothing():
    base = vfjax.preset("N1")
    ref = np.asarray(vfjax.simulate(base, FPS, 201).area)
    for effect in (
        GlottalGap(),
        CubicStiffness(),
        PressureModulation(f_m=7.0, phi=0.5),
        MucosalDelay(),
    ):
        for name, off in type(effect).off_values.items():
            assert float(effect.__getattribute__(type(effect).parameters[name][0])) == off
        gaw = np.asarray(vfjax.simulate(base.with_effect(effect), FPS, 201).area)
        np.testing.assert_allclose(gaw, ref, rtol=0, atol=1e-9, err_msg=type(effect).__name__)


def test_glottal_gap_adds_its_area():
    base = vfjax.preset("N3")
    a_gap = 0.01
    gap = vfjax.simulate(base.with_effect(GlottalGap(a_gap=a_gap)), FPS, 201).area
    plain = vfjax.simulate(base, FPS, 201).area
    np.testing.assert_allclose(gap - plain, a_gap * 100 * float(base.params()["S"]), rtol=1e-12)


def test_cubic_stiffness_conserves_duffing_energy_and_raises_f0():
    K, M, eta, A = 3.0e5, 0.1, 200.0, 0.02  # eta A² = 0.08
    model = VocalFoldModel(Subject(mass=M), (Elastic(K=K), CubicStiffness(eta=eta)), S=1.0)
    sim = vfjax.simulate(model, 40000.0, 2001, substeps=4, initial_displacement=A)
    x, v = np.asarray(sim.displacement), np.asarray(sim.velocity)
    energy = 0.5 * M * v**2 + 0.5 * K * x**2 + 0.25 * K * eta * x**4
    assert np.ptp(energy) / energy[0] < 1e-8
    # Lindstedt-Poincaré: omega = omega0 (1 + 3/8 eta A²) to first order
    f0 = vfjax.descriptors.fundamental_frequency(x - x.min(), 40000.0)
    expected = np.sqrt(K / M) / (2 * np.pi) * (1 + 3 / 8 * eta * A**2)
    assert f0 == pytest.approx(expected, rel=3e-3)


def test_pressure_modulation_formula_and_xc():
    pm = PressureModulation(a_pm=0.06, f_m=7.0, phi=0.5)
    model = vfjax.preset("N2").with_effect(pm)
    t = jnp.linspace(0, 0.2, 11)
    np.testing.assert_allclose(
        model.pressure(t), 11250.0 * (1 + 0.06 * np.sin(2 * np.pi * 7 * t + 0.5))
    )
    assert float(model.subcritical_displacement()) == float(
        vfjax.preset("N2").subcritical_displacement()
    )
    with pytest.raises(ValueError, match="a_pm"):
        PressureModulation(a_pm=1.5)


def test_time_shift_moves_only_the_frames():
    """A modulation's clock starts at t_start whatever the time shift: the frames of a
    shifted simulation are the unshifted simulation's later frames (the fit's swarm reads
    every shift from one simulation; its LM simulates each shift; both must agree)."""
    model = vfjax.preset("N2").with_effect(PressureModulation(a_pm=0.06, f_m=7.0, phi=0.5))
    k = 9  # frames
    kwargs = {"t_start": 0.03, "max_time_shift": 0.005}
    plain = vfjax.simulate(model, FPS, 60, **kwargs).area
    shifted = vfjax.simulate(model, FPS, 60, time_shift=k / FPS, **kwargs).area
    np.testing.assert_allclose(shifted[:-k], plain[k:], rtol=0, atol=1e-9)
    assert float(jnp.max(jnp.abs(shifted - plain))) > 1.0  # the shift did move the frames


def test_a_modulation_needs_a_longer_warmup():
    base = vfjax.preset("N2")
    assert vfjax.default_warmup(base) == 0.02
    assert vfjax.default_warmup(base.with_effect(PressureModulation())) == 0.1
    rec = demo_recording("N2", effect=PressureModulation(a_pm=0.06, f_m=7.0, phi=0.5))
    assert rec.metadata["hidden_effect"] == "PressureModulation"
    # the demo data start after the model's warm-up: the true model, refitted for the time
    # shift and S only, reaches the noise floor (2 px on a ~500 px GAW)
    truth = base.with_effect(PressureModulation(a_pm=0.06, f_m=7.0, phi=0.5))
    fit = vfjax.fit(
        truth,
        rec,
        params=("S", "a_pm"),
        swarm=vfjax.Swarm(size=4, iterations=2),
        bounds={"a_pm": (0.0599, 0.0601)},
        progress=False,
    )
    assert fit.sampling.warmup == 0.1
    noise = rec.n_frames * 2.0**2 / float(np.sum(rec.area**2))
    assert fit.nmse < 2.0 * noise


def test_mucosal_delay_shows_the_narrower_margin():
    base = vfjax.preset("N1")
    tau = 3e-4
    sim = vfjax.simulate(base.with_effect(MucosalDelay(tau=tau)), FPS, 201)
    plain = vfjax.simulate(base, FPS, 201)
    t = plain.time
    x_now = plain.dense.displacement(t)
    x_then = plain.dense.displacement(t - tau)
    s, l, a0 = float(base.params()["S"]), 1.6, 0.05
    expected = 100 * s * (a0 + 2 * l * np.minimum(x_now, x_then))
    np.testing.assert_allclose(sim.area, expected, rtol=1e-10, atol=1e-9)
    assert float(jnp.sum(sim.area)) < float(jnp.sum(plain.area))  # it narrows the glottis
    with pytest.raises(ValueError, match="tau"):
        MucosalDelay(tau=-1.0)
