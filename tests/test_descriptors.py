"""GAW descriptors on waveforms whose values are known analytically."""

import numpy as np
import pytest

from vfjax.descriptors import describe, detect_cycles, fundamental_frequency

FPS = 4000.0


def pulse_train(periods, t_open, t_close, amplitudes, gap=0.0, lead=7):
    """Piecewise-linear GAW: per cycle a linear rise over t_open frames, a linear fall over
    t_close frames, then closed (at ``gap``) for the rest of the period (all in frames)."""
    out = [np.full(lead, gap)]
    for T, a in zip(periods, amplitudes):
        rise = gap + a * np.arange(t_open) / t_open
        fall = gap + a * (1 - np.arange(t_close) / t_close)
        out += [rise, fall, np.full(T - t_open - t_close, gap)]
    out.append(np.full(3, gap))
    return np.concatenate(out)


def test_quotients_of_a_linear_pulse_train():
    T, To, Tc, a, g, eps = 40, 12, 6, 200.0, 10.0, 0.05
    area = pulse_train([T] * 8, To, Tc, [a] * 8, gap=g)
    d = describe(area, FPS, level=eps)
    assert d.n_cycles == 7
    assert d.f0 == pytest.approx(FPS / T, rel=1e-9)
    # the opening/closing instants sit at the 5 % level on the linear flanks
    assert d.open_quotient == pytest.approx((1 - eps) * (To + Tc) / T, rel=1e-9)
    assert d.speed_quotient == pytest.approx(To / Tc, rel=1e-9)
    assert d.closing_quotient == pytest.approx((1 - eps) * Tc / T, rel=1e-9)
    assert d.asymmetry_quotient == pytest.approx(To / (To + Tc), rel=1e-9)
    assert d.speed_index == pytest.approx((To - Tc) / (To + Tc), rel=1e-9)
    assert d.madr == pytest.approx(a / Tc * FPS, rel=1e-9)
    assert d.amplitude_quotient == pytest.approx(Tc / FPS, rel=1e-9)
    assert d.naq == pytest.approx(Tc / T, rel=1e-9)
    assert d.glottal_gap_index == pytest.approx(g / (g + a), rel=1e-9)
    assert d.closed_phase_level == pytest.approx(g)
    assert d.amplitude == pytest.approx(a)
    assert d.jitter == pytest.approx(0.0, abs=1e-12)
    assert d.shimmer == pytest.approx(0.0, abs=1e-12)


def test_jitter_and_shimmer_of_alternating_cycles():
    periods = [40, 44] * 5
    amps = [200.0, 180.0] * 5
    d = describe(pulse_train(periods, 10, 6, amps), FPS)
    # every consecutive pair differs by 4 frames and 20 units
    assert d.jitter == pytest.approx(4 / np.mean(periods[1:-1]), rel=0.03)
    assert d.shimmer == pytest.approx(20 / 190.0, rel=0.03)
    assert d.f0 == pytest.approx(FPS / 42, rel=0.02)


def test_sine_f0():
    t = np.arange(400) / FPS
    area = 100 * (1 + np.sin(2 * np.pi * 173.0 * t))
    assert fundamental_frequency(area, FPS) == pytest.approx(173.0, rel=1e-3)
    # sampled minima miss the true zero by at most 1 - cos(pi f0 / fps)
    bound = 1 - np.cos(np.pi * 173.0 / FPS)
    assert 0 <= describe(area, FPS).glottal_gap_index <= bound / 2


def test_no_cycle_warns_and_returns_nan():
    with pytest.warns(UserWarning, match="no complete glottal cycle"):
        d = describe(np.ones(50), FPS)
    assert d.n_cycles == 0 and np.isnan(d.open_quotient)
    assert detect_cycles(np.ones(50), FPS) == []


def test_bad_input_raises():
    with pytest.raises(ValueError, match="NaN"):
        describe(np.array([1.0, np.nan, 2.0]), FPS)
    with pytest.raises(ValueError, match="fps"):
        describe(np.ones(10), 0.0)


def test_a_cycle_without_closing_time_has_no_speed_quotient():
    """A coarsely sampled, noisy GAW (about 7 frames a cycle) with a cycle whose peak frame
    is where it closes: that cycle has no speed quotient; the others' mean is the GAW's."""
    a = np.array(
        [90, 15, 15, 12, 78, 64, 11, 8, 16, 95, 13, 10, 13, 79, 80, 25, 17, 9, 85, 19]
        + [14, 7, 74, 77, 15, 11, 15, 90, 27, 12, 5, 76, 83, 21, 10, 12, 104, 40, 14, 15]
        + [51, 88, 8, 14, 10, 95, 46, 13, 13, 47, 88, 10, 19, 15, 96, 62, 7, 16, 36, 95],
        dtype=float,
    )
    cycles = detect_cycles(a, 4000.0, 0.05)
    assert any(c.closing == c.peak for c in cycles)
    sq = [(c.peak - c.opening) / (c.closing - c.peak) for c in cycles if c.closing > c.peak]
    assert describe(a, 4000.0).speed_quotient == pytest.approx(np.mean(sq), rel=1e-12)
