"""GAW descriptors, computed the same way for measured and simulated waveforms.

Cycles. A cycle runs from one glottal opening instant to the next. Within a cycle, with
``A_min`` its minimum (the closed-phase level) and ``amp = A_max - A_min`` its amplitude, the
*opening instant* is where the area rises through ``A_min + level * amp`` and the *closing
instant* where it falls back through it (``level`` = 5 % by default), both located to a fraction
of a frame by linear interpolation. The peak instant is the frame of maximum area.

Per cycle, with T the cycle length, T_op = peak - opening and T_cl = closing - peak:

| descriptor | definition | reference |
|---|---|---|
| f0 | 1 / mean T | |
| open quotient, OQ | (T_op + T_cl) / T | Timcke, von Leden & Moore 1958 |
| speed quotient, SQ | T_op / T_cl | Timcke et al. 1958 |
| closing quotient, CQ | T_cl / T | Holmberg, Hillman & Perkell 1988 |
| asymmetry quotient, AsyQ | T_op / (T_op + T_cl) | Dejonckere 1981 |
| speed index, SI | (T_op - T_cl) / (T_op + T_cl) | Dejonckere 1981 |
| maximum area declination rate, MADR | max of -dA/dt in the cycle (unit/s) | Holmberg et al. 1988 |
| amplitude quotient, AQ | amp / MADR (s) | Alku & Vilkman 1996 |
| normalised amplitude quotient, NAQ | AQ / T | Alku, Bäckström & Vilkman 2002 |
| glottal gap index, GGI | A_min / A_max | Patel, Dubrovskiy & Döllinger 2014 |
| closed-phase level | A_min (unit) | |
| amplitude | A_max - A_min (unit) | |
| jitter (local) | mean abs(T_i - T_i+1) / mean T | Baken & Orlikoff 2000 |
| shimmer (local) | mean abs(amp_i - amp_i+1) / mean amp | Baken & Orlikoff 2000 |

dA/dt is the central difference of the frames. Quotients are means over the complete cycles
(those in which they are defined: a cycle whose peak frame is where it opens has no AsyQ).
"""

import dataclasses
import math
import warnings

import numpy as np


def _as_waveform(area, fps):
    area = np.asarray(area, dtype=float)
    if area.ndim != 1:
        raise ValueError(f"area must be one-dimensional, got shape {area.shape}")
    if not np.all(np.isfinite(area)):
        raise ValueError("area has NaN or infinite values")
    if not (np.isfinite(fps) and fps > 0):
        raise ValueError(f"fps (frame rate) must be > 0 Hz, got {fps}")
    return area


def cycle_starts(area, fps: float, level: float = 0.5) -> np.ndarray:
    """Times (s) at which the GAW rises through ``min + level * (max - min)``.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: frame rate (Hz).
        level: the crossing level as a fraction of the waveform's range.
    """
    area = _as_waveform(area, fps)
    lo, hi = area.min(), area.max()
    if hi <= lo:
        return np.zeros(0)
    thr = lo + level * (hi - lo)
    i = np.nonzero((area[:-1] < thr) & (area[1:] >= thr))[0]
    frac = (thr - area[i]) / (area[i + 1] - area[i])
    return (i + frac) / fps


#: The fundamental frequencies of phonation (Hz): from a low male voice to the top of a
#: soprano's modal register. A recording whose f0 lies outside was most likely given the wrong
#: frame rate (`f0_words`).
PHONATION_F0_HZ = (50.0, 1000.0)
#: The pulse rates of vocal fry (Hz) that lie below `PHONATION_F0_HZ`: an f0 there may be
#: fry rather than a wrong frame rate, and `f0_words` says so.
VOCAL_FRY_HZ = (20.0, 50.0)

#: A stretch of a GAW without a glottal cycle longer than this many cycle lengths is a
#: phonation break (`phonation_breaks`): one missed cycle is not (a weak cycle below the
#: detection level, a segmentation glitch of a frame or two), two or more are.
BREAK_CYCLES = 2.5

#: The level at which `phonation_breaks` and `f0_words` find cycle starts (`cycle_starts`):
#: a quarter of the waveform's range, so that cycles of small amplitude count.
_START_LEVEL = 0.25


def _cycles_among(lengths: np.ndarray) -> np.ndarray:
    """Which of the times between consecutive cycle starts (or openings) are cycles: those
    at most `BREAK_CYCLES` times their median (a longer one spans a phonation break)."""
    return lengths <= BREAK_CYCLES * np.median(lengths)


def _frames_of(begin: float, end: float, fps: float) -> slice:
    """The frames from ``begin`` to ``end`` (s from the first frame), both ends included."""
    return slice(int(math.ceil(begin * fps - 1e-9)), int(math.floor(end * fps + 1e-9)) + 1)


def phonation_breaks(
    area: np.ndarray, fps: float, level: float = _START_LEVEL
) -> list[tuple[float, float]]:
    """The stretches of a GAW in which no glottal cycle starts: phonation stopped (voice
    onset or offset within the recording, a break) or the glottis lost by the segmentation
    (hidden by the epiglottis, out of focus). A model of sustained phonation does not follow
    them, and a fit across one describes neither part.

    A stretch is found where the time between consecutive cycle starts (`cycle_starts` at
    ``level``), or from the first frame to the first start, or from the last start to the
    last frame, exceeds `BREAK_CYCLES` times the cycle length (the median time between
    consecutive starts, which a break does not move), and the GAW within it moves by less
    than ``level`` of its range: a glottis that vibrates but misses the crossings (a
    recording of three frames a cycle, whose samples beat with the cycle) makes no break.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: frame rate (Hz).
        level: the cycle starts' crossing level, a fraction of the waveform's range (low, so
            that cycles of small amplitude count).

    Returns:
        ``(start, end)`` of each stretch (s from the first frame: from a cycle length after
        the last cycle start before it, or the first frame, to the next cycle start, or the
        last frame), in order; empty where the glottis vibrates throughout or fewer than two
        cycles start (no cycle length).
    """
    area = _as_waveform(area, fps)
    starts = cycle_starts(area, fps, level)
    if len(starts) < 2:
        return []
    period = float(np.median(np.diff(starts)))
    edges = np.concatenate([[0.0], starts, [(area.size - 1) / fps]])
    long = np.flatnonzero(np.diff(edges) > BREAK_CYCLES * period)
    # each stretch from the end of the cycle before it (a cycle length after its start)
    stretches = [(float(edges[k] + (period if k else 0.0)), float(edges[k + 1])) for k in long]

    def still(begin, end):  # no movement of ``level`` of the range within it
        inner = area[_frames_of(begin, end, fps)]
        return inner.size == 0 or np.ptp(inner) < level * np.ptp(area)

    return [stretch for stretch in stretches if still(*stretch)]


class RecordingWarning(UserWarning):
    """A recording that a model of sustained phonation does not describe as it was given
    (`recording_cautions`): `vfjax.fit_recordings` warns of it."""


def recording_cautions(area: np.ndarray, fps: float, name: str = "the recording") -> list[str]:
    """What a model of sustained phonation cannot describe in a GAW as it was given, each in a
    sentence: a GAW that is not periodic (`periodicity_words`; then that alone, as its
    "cycles" are no glottal cycles), else its stretches without glottal cycles
    (`phonation_breaks`, `breaks_words`) and an f0 outside phonation's (`f0_words`).

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: the frame rate it was given (Hz).
        name: what the sentences call the recording.
    """
    breaks = phonation_breaks(area, fps)
    aperiodic = periodicity_words(area, fps, name, breaks)
    if aperiodic:
        return [aperiodic]
    found = (breaks_words(breaks, name), f0_words(area, fps, name))
    return [words for words in found if words]


def f0_words(area: np.ndarray, fps: float, name: str = "the recording") -> str:
    """A caution where the GAW's f0 lies outside `PHONATION_F0_HZ`: the frame rate it was
    given is most likely not the camera's. The f0 is the inverse of the median time between
    cycle starts (as `phonation_breaks` finds them), which a phonation break does not move
    (`fundamental_frequency` leaves breaks out of its mean).

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: the frame rate it was given (Hz).
        name: what the sentence calls the recording.

    Returns:
        The sentence; "" where f0 lies within the range or no f0 is found.
    """
    starts = cycle_starts(area, fps, _START_LEVEL)
    if len(starts) < 2:
        return ""
    f0 = 1.0 / float(np.median(np.diff(starts)))
    low, high = PHONATION_F0_HZ
    if low <= f0 <= high:
        return ""
    fry = " (or vocal fry, whose pulses can come slower)" if VOCAL_FRY_HZ[0] <= f0 < low else ""
    return (
        f"{name} has an f0 of {f0:.0f} Hz at the {fps:g} fps it was given, outside the "
        f"{low:.0f}-{high:.0f} Hz of phonation{fry}: check the camera's frame rate (a fit "
        "describes a glottis at that f0)"
    )


def break_spans(breaks: list[tuple[float, float]]) -> str:
    """`phonation_breaks`' stretches as text, in ms ("15.2-29.8 ms, ..."; "" where none).

    Arguments:
        breaks: the stretches (`phonation_breaks`: start and end, s).
    """
    return ", ".join(f"{a * 1e3:.1f}-{b * 1e3:.1f} ms" for a, b in breaks)


def breaks_words(breaks: list[tuple[float, float]], name: str = "the recording") -> str:
    """`phonation_breaks` in a sentence, with what to do about them.

    Arguments:
        breaks: the stretches (`phonation_breaks`: start and end, s).
        name: what the sentence calls the recording.

    Returns:
        The sentence; "" where there is no stretch.
    """
    if not breaks:
        return ""
    return (
        f"{name} has no glottal cycle in {break_spans(breaks)} (a phonation break, the "
        "glottis lost by the segmentation, or cycles skipped, as a slow pressure modulation "
        "can skip them): a model of sustained phonation follows neither a break nor a lost "
        "glottis, so fit the frames of phonation alone where it is one of those"
    )


def periodicity(
    area: np.ndarray,
    fps: float,
    f0_range: tuple[float, float] | None = PHONATION_F0_HZ,
    frames: np.ndarray | None = None,
) -> tuple[float, float]:
    """How periodic a waveform is: the largest normalised autocorrelation over the lags of a
    glottal period (``f0_range``, Hz), and that lag (s).

    A vibrating glottis gives 0.95 or more (the shared real and synthetic recordings: 0.97 to
    1.0); white noise of 100 frames about 0.3 to 0.45. Lags are kept to those whose pairs of
    frames span half of the waveform or more. Returns (0, nan) for a constant waveform or
    one too short to hold two periods.

    Arguments:
        area: the waveform, one value per frame (any unit).
        fps: frame rate (Hz).
        f0_range: the frequencies (Hz) whose periods are searched; None: every lag from the
            autocorrelation's first fall to zero or below (any period, whatever frame rate
            the waveform was given: a smooth waveform correlates highly over a fraction of
            its period).
        frames: which frames count (booleans, one per frame; default all): a correlation
            takes the pairs of frames that both count, about their mean (the frames of
            phonation, without its breaks).
    """
    a = _as_waveform(area, fps)
    n = a.size
    on = np.ones(n, bool) if frames is None else np.asarray(frames, bool)
    if on.shape != a.shape:
        raise ValueError(f"frames must hold one boolean per frame ({n}), got {on.shape}")
    if n < 2 or not on.any():
        return 0.0, float("nan")
    x = np.where(on, a - a[on].mean(), 0.0)
    if not np.any(x):
        return 0.0, float("nan")
    # every lag's sums over the pairs of counted frames at once, by FFT (O(n log n): a
    # recording of a million frames takes a second)
    m = on.astype(float)
    size = 1 << (2 * n - 1).bit_length()
    fx, fm, fxx = (np.fft.rfft(v, size) for v in (x, m, x * x))

    def lagged(f, g):  # sum over t of f_t g_{t+k}, for k = 0 .. n - 1
        return np.fft.irfft(np.conj(f) * g, size)[:n]

    products, pairs = lagged(fx, fx), np.rint(lagged(fm, fm))
    first, second = lagged(fxx, fm), lagged(fm, fxx)  # each pair's first and second frame
    lo, hi = 1, n - 1
    if f0_range is not None:
        lo = max(1, int(math.floor(fps / f0_range[1])))
        hi = min(hi, int(math.ceil(fps / f0_range[0])))
    short = np.flatnonzero(2 * pairs[lo:] < on.sum())  # pairs spanning under half of it
    hi = min(hi, lo + int(short[0]) - 1) if short.size else hi
    if hi < lo:
        return 0.0, float("nan")
    lags = np.arange(lo, hi + 1)
    denom = np.sqrt(np.clip(first[lags], 0.0, None) * np.clip(second[lags], 0.0, None))
    r = np.where(denom > 0, products[lags] / np.where(denom > 0, denom, 1.0), 0.0)
    if f0_range is None:  # from the first fall to zero on
        fallen = np.flatnonzero(r <= 0.0)
        if not fallen.size:  # (no period within the lags)
            return 0.0, float("nan")
        r, lags = r[fallen[0] :], lags[fallen[0] :]
    best = int(np.argmax(r))
    return float(r[best]), float(lags[best] / fps)


#: A GAW whose autocorrelation over any period (`phonation_periodicity`) stays below this
#: is not that of a vibrating glottis (`periodicity_words`), and a video whose segmented
#: area's does over glottal periods holds none (`vfjax.segmentation`). A vibrating glottis
#: gives 0.95 or more (the shared recordings and clips 0.976-1.0), the strongest pressure
#: modulation of the injection-recovery benchmark (depth 0.4 at 8 Hz, 50 ms) 0.68 and more,
#: white noise of 100 frames or more at most 0.45 and of 50 frames at most about 0.6.
MIN_PERIODICITY = 0.6


def phonation_periodicity(
    area: np.ndarray, fps: float, breaks: list[tuple[float, float]] | None = None
) -> float:
    """The periodicity of a GAW's frames of phonation: `periodicity` over any period of its
    frames outside its `phonation_breaks`, or of all of them where those hold under a
    quarter of it (the "breaks" of noise leave fragments, whose correlations tell nothing).

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: the frame rate it was given (Hz).
        breaks: its `phonation_breaks`, where they are already found (default: found here).
    """
    frames = np.ones(np.size(area), bool)
    for begin, end in phonation_breaks(area, fps) if breaks is None else breaks:
        frames[_frames_of(begin, end, fps)] = False
    if 4 * frames.sum() < frames.size:
        frames[:] = True
    return periodicity(area, fps, f0_range=None, frames=frames)[0]


def periodicity_words(
    area: np.ndarray,
    fps: float,
    name: str = "the recording",
    breaks: list[tuple[float, float]] | None = None,
) -> str:
    """A caution where the GAW is not periodic (`phonation_periodicity` below
    `MIN_PERIODICITY`): noise, a segmentation that lost the glottis, a vibration too
    irregular for a model of sustained phonation, or a recording too short to hold two
    cycles (at the frame rate it was given), whose fit describes little of it.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: the frame rate it was given (Hz).
        name: what the sentence calls the recording.
        breaks: its `phonation_breaks`, where they are already found (default: found here).

    Returns:
        The sentence; "" where the GAW is periodic.
    """
    score = phonation_periodicity(area, fps, breaks)
    if score >= MIN_PERIODICITY:
        return ""
    return (
        f"{name} is not periodic (its autocorrelation reaches {score:.2f} at best over any "
        f"period up to half its length, where a vibrating glottis gives 0.95 or more): it is "
        "noise, a segmentation that lost the glottis, a vibration too irregular for a model "
        "of sustained phonation, or too short to hold two cycles, and a fit describes little "
        "of it"
    )


def fundamental_frequency(area: np.ndarray, fps: float) -> float:
    """f0 (Hz): the inverse of the mean cycle length, the time between consecutive cycle
    starts (`cycle_starts`), leaving out the stretches longer than `BREAK_CYCLES` times
    their median (a phonation break is no cycle); NaN with fewer than two cycle starts.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: frame rate (Hz).
    """
    starts = cycle_starts(area, fps)
    if len(starts) < 2:
        return float("nan")
    lengths = np.diff(starts)
    cycles = _cycles_among(lengths)
    if cycles.all():
        return float((len(starts) - 1) / (starts[-1] - starts[0]))
    return float(1.0 / lengths[cycles].mean())


@dataclasses.dataclass(frozen=True)
class Cycle:
    """One glottal cycle (times in s from the first frame, areas in the GAW's unit)."""

    opening: float
    peak: float
    closing: float
    end: float  # the next cycle's opening
    minimum: float
    maximum: float
    madr: float

    @property
    def period(self) -> float:
        return self.end - self.opening

    @property
    def amplitude(self) -> float:
        return self.maximum - self.minimum


def _rise(a, i, thr):
    return i + (thr - a[i]) / (a[i + 1] - a[i])


def _fall(a, i, thr):
    return i + (a[i] - thr) / (a[i] - a[i + 1])


def detect_cycles(area: np.ndarray, fps: float, level: float = 0.05) -> list[Cycle]:
    """The complete glottal cycles of a GAW (see the module's definitions); a stretch from
    one opening to the next longer than `BREAK_CYCLES` times their median (a phonation
    break) is no cycle.

    Arguments:
        area: glottal area waveform, one value per frame (any unit).
        fps: frame rate (Hz).
        level: the opening and closing instants' level, a fraction of each cycle's amplitude.
    """
    a = _as_waveform(area, fps)
    starts = cycle_starts(a, fps)
    if len(starts) < 2:
        return []
    mids = np.round(starts * fps).astype(int)  # frames on each cycle's rising edge
    rate = np.gradient(a) * fps
    cycles = []
    # each cycle: from the minimum before one rising edge to the minimum before the next
    lows = [
        int(np.argmin(a[(mids[k - 1] if k else 0) : mids[k] + 1])) + (mids[k - 1] if k else 0)
        for k in range(len(mids))
    ]
    openings = []
    for k in range(len(mids)):
        lo_i = lows[k]
        base = a[lo_i]
        # (to the next cycle's minimum, inclusive: two cycles' minima can share a frame)
        seg_max = a[lo_i : (lows[k + 1] + 1 if k + 1 < len(lows) else a.size)].max()
        thr = base + level * (seg_max - base)
        i = lo_i
        while i < mids[k] and a[i + 1] < thr:
            i += 1
        openings.append(_rise(a, i, thr) if a[i + 1] != a[i] else float(i))
    for k in range(len(mids) - 1):
        lo_i, hi_i = lows[k], lows[k + 1]
        seg = a[lo_i : hi_i + 1]
        base = min(seg.min(), a[hi_i])
        p = lo_i + int(np.argmax(seg))
        peak = float(p)
        amp = a[p] - base
        thr = base + level * amp
        j = p
        while j < hi_i and a[j + 1] > thr:
            j += 1
        closing = _fall(a, j, thr) if j < hi_i and a[j] != a[j + 1] else float(j)
        cycles.append(
            Cycle(
                opening=openings[k] / fps,
                peak=peak / fps,
                closing=closing / fps,
                end=openings[k + 1] / fps,
                minimum=float(seg.min()),
                maximum=float(a[p]),
                madr=float(max(0.0, -rate[p : hi_i + 1].min())),
            )
        )
    # a "cycle" across a phonation break is none
    lengths = np.array([c.end - c.opening for c in cycles])
    if lengths.size and not _cycles_among(lengths).all():
        cycles = [c for c, kept in zip(cycles, _cycles_among(lengths)) if kept]
    return cycles


@dataclasses.dataclass(frozen=True)
class Descriptors:
    """GAW descriptors (see the module for definitions); NaN where undefined."""

    n_cycles: int
    f0: float  # Hz
    open_quotient: float
    speed_quotient: float
    closing_quotient: float
    asymmetry_quotient: float
    speed_index: float
    madr: float  # unit/s
    amplitude_quotient: float  # s
    naq: float
    glottal_gap_index: float
    closed_phase_level: float  # unit
    amplitude: float  # unit
    jitter: float  # fraction
    shimmer: float  # fraction

    def as_dict(self) -> dict:
        return dataclasses.asdict(self)


def describe(area, fps: float, level: float = 0.05) -> Descriptors:
    """All descriptors of a GAW; warns and returns NaNs when no complete cycle is found."""
    cycles = detect_cycles(area, fps, level)
    nan = float("nan")
    if not cycles:
        warnings.warn("no complete glottal cycle found: descriptors are NaN", stacklevel=2)
        return Descriptors(0, *([nan] * 14))
    T = np.array([c.period for c in cycles])
    t_op = np.array([c.peak - c.opening for c in cycles])
    t_cl = np.array([c.closing - c.peak for c in cycles])
    amp = np.array([c.amplitude for c in cycles])
    madr = np.array([c.madr for c in cycles])
    aq = np.where(madr > 0, amp / np.where(madr > 0, madr, 1.0), nan)
    sq = np.where(t_cl > 0, t_op / np.where(t_cl > 0, t_cl, 1.0), nan)

    def rel_diff(x):
        return float(np.mean(np.abs(np.diff(x))) / np.mean(x)) if len(x) > 1 else nan

    def mean(x):  # over the cycles where it is defined (NaN where it is in none)
        x = np.asarray(x, float)
        return float(np.mean(x[np.isfinite(x)])) if np.isfinite(x).any() else nan

    # a quotient whose denominator is zero in a cycle (a peak frame where the cycle opens
    # or closes, a cycle that never rises above zero) is undefined there, not an error
    with np.errstate(divide="ignore", invalid="ignore"):
        return Descriptors(
            n_cycles=len(cycles),
            f0=float(1.0 / T.mean()),
            open_quotient=float(np.mean((t_op + t_cl) / T)),
            # a cycle sampled so coarsely that its peak frame is where it closes has no closing
            # time to divide by: it has no speed quotient of its own
            speed_quotient=mean(sq),
            closing_quotient=float(np.mean(t_cl / T)),
            asymmetry_quotient=mean(t_op / (t_op + t_cl)),
            speed_index=mean((t_op - t_cl) / (t_op + t_cl)),
            madr=float(madr.mean()),
            amplitude_quotient=mean(aq),
            naq=mean(aq / T),
            glottal_gap_index=mean([c.minimum / c.maximum for c in cycles]),
            closed_phase_level=float(np.mean([c.minimum for c in cycles])),
            amplitude=float(amp.mean()),
            jitter=rel_diff(T),
            shimmer=rel_diff(amp),
        )


def estimate_closure_duration(recording, levels=(0.1, 0.2)) -> float | None:
    """Closed-phase duration (s) measured on the GAW, or None if the glottis never closes.

    For each closed phase, the times at which the area falls through and rises back through
    ``levels`` (fractions of the peak) are located to a fraction of a frame, and the width of
    the closed phase is extrapolated linearly to zero level: ``2 w(L1) - w(L2)``. The longest
    complete closed phase is returned: the hold lasts t_c in every cycle that closes fully,
    while cycles that barely close (a modulated pressure, a gap) give shorter ones. The paper
    takes t_c from the measured GAW; this gives it without the bias of counting frames under
    a threshold.
    """
    a = recording.area
    peak = a.max()
    l1, l2 = levels
    low = a <= l1 * peak
    if not low.any() or low.all():
        return None

    def crossing(i, level, down):
        # fractional frame index where a crosses level*peak between frames i and i+1
        thr = level * peak
        return (
            i + (a[i] - thr) / (a[i] - a[i + 1]) if down else i + (thr - a[i]) / (a[i + 1] - a[i])
        )

    edges = np.diff(np.r_[0, low.astype(int), 0])
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    widths = []
    for s0, e0 in zip(starts, ends):
        if s0 == 0 or e0 >= a.size:
            continue  # a closed phase cut by the recording's ends
        w = []
        for level in (l1, l2):
            i = s0 - 1
            while i > 0 and a[i] <= level * peak:
                i -= 1
            j = e0 - 1
            while j < a.size - 1 and a[j + 1] <= level * peak:
                j += 1
            if a[i] <= level * peak or j >= a.size - 1:
                break
            w.append(crossing(j, level, down=False) - crossing(i, level, down=True))
        if len(w) == 2:
            widths.append(2 * w[0] - w[1])
    if not widths or max(widths) <= 0:
        return None  # no closed phase long enough to measure
    return float(np.max(widths)) / recording.fps


def noise_level(measured: np.ndarray, fitted: np.ndarray) -> float:
    """Standard deviation of white measurement noise on a GAW (its unit), from a fit's
    residual r = measured - fitted: the robust (MAD) spread of r minus its local quadratic
    trend (Savitzky-Golay, 5 frames), scaled by 1 / sqrt(1 - 17/35) (the share of white
    noise such a fit leaves). Only frames where both GAWs are open in all 5 frames count (a
    clipped closed phase shows no noise); a smooth misfit barely shows at all."""
    from scipy.signal import savgol_filter

    m, g = np.asarray(measured, dtype=float), np.asarray(fitted, dtype=float)
    r = m - g
    if r.size < 9:
        return 0.0
    e = r - savgol_filter(r, 5, 2)
    open_ = np.convolve(((m > 0) & (g > 0)).astype(float), np.ones(5), "same") == 5
    open_[:2] = open_[-2:] = False
    if open_.sum() < 8:
        return 0.0
    e = e[open_]
    return float(1.4826 * np.median(np.abs(e - np.median(e))) / math.sqrt(1.0 - 17.0 / 35.0))
