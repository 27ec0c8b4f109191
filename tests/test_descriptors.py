"""GAW descriptors on waveforms whose values are known analytically."""

import re

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


def test_phonation_breaks_are_the_stretches_without_cycles(shared_dir):
    """`phonation_breaks`: none on a vibrating glottis (a demo recording, the shared real
    contours and synthetic recordings: sustained phonation); where the glottis stops for a
    while (frames set to zero at the start, in the middle, at the end) the stretch from the
    end of the last cycle before it to the next cycle start, to within a cycle; one missing
    cycle is no break."""
    import vfjax
    from vfjax.descriptors import breaks_words, cycle_starts, phonation_breaks
    from vfjax.recording import load_contours

    rec = vfjax.datasets.demo_recording("N1", seed=1, n_frames=401)  # 4 kHz, 125 Hz
    a, fps = rec.area, rec.fps
    assert phonation_breaks(a, fps) == [] and breaks_words([]) == ""
    starts = cycle_starts(a, fps, 0.25)
    period = float(np.median(np.diff(starts)))
    assert period == pytest.approx(0.008, rel=0.05)
    for lo, hi in ((0, 150), (100, 250), (200, 401)):
        stopped = np.where((np.arange(a.size) >= lo) & (np.arange(a.size) < hi), 0.0, a)
        (begin, end), *more = phonation_breaks(stopped, fps)
        assert more == []
        # the stretch holds the zeroed frames but for the last cycle's tail, within a cycle
        assert lo / fps - 1e-9 <= begin + period and begin <= lo / fps + period
        assert (hi - 1) / fps <= end <= hi / fps + period
    words = breaks_words(phonation_breaks(np.where(np.arange(a.size) >= 200, 0.0, a), fps), "r")
    assert words.startswith("r has no glottal cycle in ") and "ms (a phonation break" in words
    # one cycle gone: two cycle lengths between starts, under `BREAK_CYCLES`
    k = int(round(starts[3] * fps)) - 2
    one = a.copy()
    one[k : k + int(round(period * fps))] = 0.0
    assert phonation_breaks(one, fps) == []
    real = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
    for name, rate in real.items():
        r = load_contours(shared_dir / "data" / "real" / f"{name}_segdata.txt", rate)
        assert phonation_breaks(r.area, r.fps) == [], name
    for name in ("syn_base", "syn_gap", "syn_tremor"):
        r = vfjax.load_recording(shared_dir / "data" / "synthetic" / f"{name}.csv")
        assert phonation_breaks(r.area, r.fps) == [], name


def test_an_f0_outside_phonation_is_named_as_a_frame_rate_to_check(shared_dir):
    """`f0_words`: the demo recording (N1, 125 Hz at 4 kHz) and the shared real contours at
    their cameras' rates lie within `PHONATION_F0_HZ`; the demo given 1 500 or 40 000 fps has
    an f0 of 47 or 1 250 Hz, which is named with the rate to check."""
    import vfjax
    from vfjax.descriptors import PHONATION_F0_HZ, f0_words, fundamental_frequency
    from vfjax.recording import load_contours

    rec = vfjax.datasets.demo_recording("N1", seed=1, n_frames=201)
    assert f0_words(rec.area, rec.fps) == ""
    for fps in (1500.0, 40000.0):
        f0 = fundamental_frequency(rec.area, fps)
        assert f0 == pytest.approx(fundamental_frequency(rec.area, rec.fps) * fps / rec.fps)
        assert not PHONATION_F0_HZ[0] <= f0 <= PHONATION_F0_HZ[1]
        words = f0_words(rec.area, fps, "r")
        assert words.startswith(f"r has an f0 of {f0:.0f} Hz at the {fps:g} fps it was given")
    real = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
    for name, rate in real.items():
        r = load_contours(shared_dir / "data" / "real" / f"{name}_segdata.txt", rate)
        assert f0_words(r.area, r.fps) == "", name


def test_a_first_fit_warns_of_what_no_model_of_sustained_phonation_describes():
    """`fit_recordings` warns (`RecordingWarning`) of each recording's `recording_cautions`
    before it fits anything (here it then refuses its arguments: no fit is made)."""
    import vfjax
    from vfjax.descriptors import RecordingWarning, recording_cautions

    rec = vfjax.datasets.demo_recording("N1", seed=1, n_frames=201)
    assert recording_cautions(rec.area, rec.fps) == []
    stopped = vfjax.Recording(np.where(np.arange(201) < 100, rec.area, 0.0), rec.fps, name="s")
    slow = vfjax.Recording(rec.area, 1500.0, name="slow")
    f0 = fundamental_frequency(slow.area, slow.fps)
    assert 40.0 < f0 < 50.0
    (words,) = recording_cautions(stopped.area, stopped.fps, "s")
    model = vfjax.initial_model(rec)
    for r, says in ((stopped, words), (slow, f"slow has an f0 of {f0:.0f} Hz at the 1500 fps")):
        with pytest.warns(RecordingWarning, match=re.escape(says)), pytest.raises(ValueError):
            vfjax.fit_recordings([r], [model, model])
