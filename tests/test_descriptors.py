"""GAW descriptors on waveforms whose values are known analytically."""

import re
import warnings

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


def test_noise_is_described_without_an_error():
    """White noise, whose chance "cycles" can share their minima's frame: every descriptor
    finite or NaN, each cycle ending after it opens, and nothing raised or warned of."""
    rng = np.random.default_rng(5)
    for _ in range(300):
        area = rng.normal(100.0, 30.0, int(rng.integers(20, 400)))
        with warnings.catch_warnings():
            warnings.simplefilter("error", RuntimeWarning)  # (no NumPy warning reaches a user)
            warnings.filterwarnings("ignore", "no complete glottal cycle")
            d = describe(area, FPS)
        assert not np.any(np.isinf(list(d.as_dict().values())))
        assert all(c.opening < c.end and c.minimum <= c.maximum for c in detect_cycles(area, FPS))


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
    from vfjax.descriptors import BREAK_CYCLES, breaks_words, cycle_starts, phonation_breaks
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
    # a glottis that vibrates throughout, sampled at three frames a cycle: its samples beat
    # with the cycle and miss the crossings for a few cycles at a time, which is no break
    n3 = vfjax.preset("N3")
    faster = n3.set(K=2.0 * float(n3.params()["K"]))
    beating = vfjax.datasets.demo_recording("N3", 1.5, 5, 2000.0, 510, model=faster)
    gaps = np.diff(cycle_starts(beating.area, beating.fps, 0.25))
    assert gaps.max() > BREAK_CYCLES * np.median(gaps)
    assert phonation_breaks(beating.area, beating.fps) == []


def test_an_f0_outside_phonation_is_named_as_a_frame_rate_to_check(shared_dir):
    """`f0_words`: the demo recording (N1, 125 Hz at 4 kHz) and the shared real contours at
    their cameras' rates lie within `PHONATION_F0_HZ`; the demo given 1 500 or 40 000 fps has
    an f0 of 47 or 1 250 Hz, which is named with the rate to check. A phonation break in the
    middle (a stretch as long as eight cycles) leaves the f0 of the cycles."""
    import vfjax
    from vfjax.descriptors import PHONATION_F0_HZ, f0_words, recording_cautions
    from vfjax.recording import load_contours

    rec = vfjax.datasets.demo_recording("N1", seed=1, n_frames=201)
    assert f0_words(rec.area, rec.fps) == ""
    starts = np.flatnonzero(
        (rec.area[:-1] < 0.25 * rec.area.max()) & (rec.area[1:] >= 0.25 * rec.area.max())
    )
    frames = float(np.median(np.diff(starts)))  # frames per cycle, to the frame
    assert FPS / frames == pytest.approx(125.0, rel=0.05)
    for fps in (1500.0, 40000.0):
        f0 = fps / frames
        assert not PHONATION_F0_HZ[0] <= f0 <= PHONATION_F0_HZ[1]
        words = f0_words(rec.area, fps, "r")
        said = float(re.match(r"r has an f0 of (\d+) Hz at the (\d+) fps it was given", words)[1])
        assert said == pytest.approx(f0, rel=0.02) and f" {fps:g} fps" in words
        assert ("or vocal fry" in words) == (f0 < 50.0)  # (47 Hz: a pulse rate of fry)
    real = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
    for name, rate in real.items():
        r = load_contours(shared_dir / "data" / "real" / f"{name}_segdata.txt", rate)
        assert f0_words(r.area, r.fps) == "", name
    long = vfjax.datasets.demo_recording("N1", seed=1, n_frames=401)
    broken = np.where((np.arange(401) >= 100) & (np.arange(401) < 350), 0.0, long.area)
    # the f0 and the cycles are those of the frames of phonation, the break left out: a
    # train of 40-frame pulses with four of its twelve cycles closed
    train = pulse_train([40] * 12, 12, 6, [200.0] * 12)
    stopped = np.where((np.arange(train.size) >= 127) & (np.arange(train.size) < 287), 0.0, train)
    assert fundamental_frequency(stopped, FPS) == pytest.approx(FPS / 40, rel=1e-9)
    d = describe(stopped, FPS)
    assert d.f0 == pytest.approx(FPS / 40, rel=1e-9) and d.n_cycles == 6
    assert d.open_quotient == pytest.approx(describe(train, FPS).open_quotient, rel=1e-9)
    (words,) = recording_cautions(broken, FPS)  # the break alone
    assert f0_words(broken, FPS) == "" and "no glottal cycle in " in words


def test_a_gaw_that_is_not_periodic_is_named(shared_dir):
    """`periodicity_words`: white noise of 101 to 1 001 frames and nine in ten random walks
    (a drifting area) are not periodic over any period, whatever frame rate they are given,
    and that alone is what `recording_cautions` says of noise (its "cycles" are none); every
    shared recording, the cohort benchmark's kind of demo recording and one whose glottis
    stops for most of it are periodic."""
    import vfjax
    from vfjax.descriptors import (
        MIN_PERIODICITY,
        periodicity,
        periodicity_words,
        recording_cautions,
    )
    from vfjax.recording import load_contours

    rng = np.random.default_rng(11)
    walks = 0
    for n in (101, 201, 1001):
        for fps in (2000.0, 8000.0):
            noise = np.abs(rng.normal(100.0, 30.0, n))
            words = periodicity_words(noise, fps, "r")
            assert words.startswith("r is not periodic (its autocorrelation reaches ")
            assert recording_cautions(noise, fps, "r") == [words]
            for _ in range(10):  # a walk can look like half a cycle now and then
                walk = np.cumsum(rng.normal(0.0, 1.0, n))
                walks += periodicity_words(walk - walk.min(), fps) != ""
    assert walks >= 54  # of 60 (about 97 % are flagged)
    # each lag's correlation (computed by FFT) is the direct one over the pairs of counted
    # frames about their mean, the lags stopping where the pairs span under half of them
    area, counted = rng.normal(0.0, 1.0, 97).cumsum(), rng.random(97) > 0.2
    area[counted] += 5 * np.sin(np.arange(97)[counted] / 2.0)
    mean = area[counted].mean()
    direct = {}
    for k in range(1, 97):
        both = counted[:-k] & counted[k:]
        if 2 * both.sum() < counted.sum():
            break
        x, y = area[:-k][both] - mean, area[k:][both] - mean
        direct[k] = x @ y / np.sqrt((x @ x) * (y @ y))
    for f0_range in ((100.0, 1000.0), (10.0, 400.0)):
        score, lag = periodicity(area, 1000.0, f0_range, frames=counted)
        low, high = np.floor(1000.0 / f0_range[1]), np.ceil(1000.0 / f0_range[0])
        ks = [k for k in direct if low <= k <= high]  # (whole frames about the periods)
        assert score == pytest.approx(max(direct[k] for k in ks), abs=1e-12)
        assert direct[round(lag * 1000.0)] == pytest.approx(score, abs=1e-12)
    # a periodic waveform correlates fully at its period, at any frame rate it is given
    sine = np.sin(2 * np.pi * np.arange(400) / 37.0)
    for fps in (100.0, 4000.0, 1e6):
        score, lag = periodicity(sine, fps, f0_range=None)
        assert score > 0.99 and round(lag * fps) % 37 == 0  # (at a multiple of the period)
    real = {"MN003_adapt": 8000.0, "FD003_pre": 8000.0, "FN003": 8000.0, "FP005_naso": 4000.0}
    for name, rate in real.items():
        r = load_contours(shared_dir / "data" / "real" / f"{name}_segdata.txt", rate)
        assert periodicity(r.area, r.fps, f0_range=None)[0] > 0.95, name
    for name in ("syn_base", "syn_gap", "syn_tremor"):  # (the tremor's modulation: 0.84)
        r = vfjax.load_recording(shared_dir / "data" / "synthetic" / f"{name}.csv")
        assert periodicity(r.area, r.fps, f0_range=None)[0] > 0.8, name
    rec = vfjax.datasets.demo_recording("N2", seed=2, n_frames=101, jitter=0.003)
    assert periodicity(rec.area, rec.fps, f0_range=None)[0] > 0.95
    # a glottis that stops for three quarters of the recording: the stretch of closure
    # correlates with itself, the cycles before it at their period
    long = vfjax.datasets.demo_recording("N1", seed=1, n_frames=401)
    stopped = np.where(np.arange(401) < 100, long.area, 0.0)
    assert periodicity(stopped, FPS, f0_range=None)[0] > MIN_PERIODICITY
    (words,) = recording_cautions(stopped, FPS, "s")
    assert words.startswith("s has no glottal cycle in ")


def test_a_first_fit_warns_of_what_no_model_of_sustained_phonation_describes():
    """`fit_recordings` warns (`RecordingWarning`) of each recording's `recording_cautions`
    before it fits anything (here it then refuses its arguments: no fit is made)."""
    import vfjax
    from vfjax.descriptors import RecordingWarning, recording_cautions

    rec = vfjax.datasets.demo_recording("N1", seed=1, n_frames=201)
    assert recording_cautions(rec.area, rec.fps) == []
    stopped = vfjax.Recording(np.where(np.arange(201) < 100, rec.area, 0.0), rec.fps, name="s")
    slow = vfjax.Recording(rec.area, 1500.0, name="slow")
    (said,) = recording_cautions(slow.area, slow.fps, "slow")
    f0 = float(re.match(r"slow has an f0 of (\d+) Hz", said)[1])
    assert 40.0 < f0 < 50.0
    (words,) = recording_cautions(stopped.area, stopped.fps, "s")
    model = vfjax.initial_model(rec)
    for r, says in ((stopped, words), (slow, f"slow has an f0 of {f0:.0f} Hz at the 1500 fps")):
        with pytest.warns(RecordingWarning, match=re.escape(says)), pytest.raises(ValueError):
            vfjax.fit_recordings([r], [model, model])
