"""Comparison of a fit with its measurement: phases, error shares, descriptors, words."""

import numpy as np

import vfjax
from vfjax import fit, initial_model
from vfjax.compare import compare, noise_level, plot_comparison
from vfjax.recording import Recording


def test_gap_is_described_in_words(shared_dir):
    rec = vfjax.load_recording(shared_dir / "data" / "synthetic" / "syn_gap.csv")
    result = fit(initial_model(rec), rec, params=("S", "K", "C_f", "t_c"), progress=False)
    c = compare(result, rec)
    assert (
        abs(sum(c.error_share.values()) - 1) < 1e-9 and abs(sum(c.time_share.values()) - 1) < 1e-9
    )
    assert c.error_share["closed"] > 0.6  # the gap's error sits in the closed phase
    words = " ".join(c.failures())
    assert "never falls below" in words and "the model closes fully" in words
    labels = [row[0] for row in c.table()]
    assert labels[:4] == ["f0", "open quotient", "speed quotient", "closing quotient"]
    assert plot_comparison(c) is not None


def test_perfect_fit_reports_no_failure():
    # N3 closes with a clear margin; the recording starts 3 ms after the fit's warm-up (within
    # its time-shift range, so the truth is in the search space)
    truth = vfjax.preset("N3")
    area = np.clip(np.asarray(vfjax.simulate(truth, 4000.0, 201, t_start=0.023).area), 0, None)
    rec = Recording(area=area, fps=4000.0)
    # the parameters the gap test fits: the same compiled programs serve both
    c = compare(fit(truth, rec, params=("S", "K", "C_f", "t_c"), progress=False), rec)
    assert c.nmse < 1e-8
    assert c.failures()[0].startswith("no clear failure")


def test_noise_level_of_white_noise_beside_a_misfit():
    """White noise of 2 units on a GAW-like wave fitted with a slightly wrong phase and
    amplitude: the estimate sees the noise, not the (smooth) misfit."""
    rng = np.random.default_rng(0)
    t = np.arange(2000) / 4000.0
    truth = 200 + 150 * np.sin(2 * np.pi * 130 * t)
    fitted = 200 + 140 * np.sin(2 * np.pi * 130 * t + 0.05)
    area = truth + rng.normal(0, 2.0, t.size)
    assert abs(noise_level(area, fitted) - 2.0) < 0.15
    # the misfit alone is no noise
    assert noise_level(truth, fitted) < 0.3
