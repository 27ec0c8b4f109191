"""Which physical effect is missing? Score tests and quick refits from a fit.

`diagnose` takes a fit of a model to a recording and asks, for each candidate effect (the
catalogue of `MODEL_SPEC.md`, the paper's own FlowSeparation and ClosureHold when switched
off, or a user's own term), two questions:

1. **Score (Lagrange-multiplier) test**, from the current fit alone. The effect is added at
   its off-value; the residual r (measured minus fitted GAW) is tested against the GAW's
   sensitivities J_e to the effect's parameters, with the sensitivities J_f to the fitted
   parameters (and the time shift) projected out. With M = I - J_f (J_f' J_f)^-1 J_f',

       u = J_e' M r,    LM = u' V^-1 u,    V = Var(u),

   asymptotically chi-square with as many degrees of freedom as columns in J_e. Residuals of
   a GAW are not independent (cycle-to-cycle variability leaves a misfit that is correlated
   within a cycle), so V is by default a heteroscedasticity- and autocorrelation-consistent
   (Newey-West, Bartlett kernel, one glottal period of bandwidth) estimate,
   V = sum_l w_l sum_t h_t h_{t-l}', h_t = (M J_e)_t r_t; ``variance="iid"`` gives the textbook
   s² J_e' M J_e. An effect whose off-value is a boundary (a gap, a delay, a strength >= 0)
   gets the one-sided test z = u / sqrt(V). Parameters that do not exist at the off-value
   (a modulation's frequency) are searched on the term's ``score_grid``, the largest statistic
   is kept and its p-value is Bonferroni-corrected over the grid; columns that belong
   together (a modulation's sine and cosine phase) are tested jointly (``score_directions``).

2. **Quick refit**: the model with the effect is refitted, warm-started from the current fit
   and from the score test's one-step estimate of the effect's parameters (a few starts),
   giving the error each effect would reach. All candidates' starts (and the control's) run
   as one `vfjax.fit_many` batch of the model extended by every candidate, each start with
   the other candidates held at their off-values (`refit_each`): one compiled program
   serves all the quick refits. The leading candidate and the control are then refitted
   once more with a larger swarm (``confirm``), so that the error and parameters reported
   for the effect to add are a thorough search's, not a quick one's. A leader whose quick
   refit already removes ``min_fall`` of the error gets a swarm sized to its dimension:
   twice the particles and a quarter more iterations per parameter beyond its first (a
   modulation's depth, frequency and phase: 4x the particles, 1.5x the iterations).

An effect is *needed* when the evidence is significant at ``alpha`` (Bonferroni-corrected
over the candidates; the evidence is twice the smaller p-value of the score test and of an F
test of the refit's error fall, on the residual's effective number of independent frames),
and its refit removes at least ``min_fall`` of the squared error, and at least
``noise_multiple`` (3) noise floors' worth of it (the NMSE that white measurement noise
alone leaves, `noise_level`): a few extra parameters fitted to noise and cycle-to-cycle
jitter remove less. (The refit's F test alone is not enough: on data with jitter and no
effect, a slow pressure modulation absorbs part of the drifting timing and its F test, even
on the effective number of frames, comes out "significant".) Falls are
measured from a control refit of the model without any effect, done the same way, so that a
refit that merely finds a better optimum of the fitted model does not count.
Candidates are ranked by the error their refit reaches (by p-value without refits). When no
effect is needed, or the best one explains little of the misfit, `Diagnosis.verdict` says so
in words, with where the model fails (`vfjax.compare`).
"""

import dataclasses
import math
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from ._fit import FitResult, Polish, Swarm, default_warmup, fit, fit_many, search_range
from .compare import Comparison, compare, noise_level
from .integrator import SampledGrid, sampled_grid, simulate_frames, window_size
from .presets import initial_model
from .recording import Recording
from .terms.base import AbstractTerm
from .terms.effects import CubicStiffness, GlottalGap, MucosalDelay, PressureModulation
from .terms.paper import ClosureHold, FlowSeparation

#: The confirming refit's swarm by default: (particles, PSO iterations) for a candidate of
#: one parameter; see `diagnose` and `confirm_swarm`.
CONFIRM = (64, 100)
#: The candidates tried by default, in this order (those already active in the model are
#: skipped; FlowSeparation and ClosureHold only when absent or switched off).
DEFAULT_CANDIDATES = (
    GlottalGap,
    CubicStiffness,
    PressureModulation,
    MucosalDelay,
    FlowSeparation,
    ClosureHold,
)


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A candidate effect: a term at its off-value and how to test it.

    Build one with `Candidate.of(TermClass)`; the settings come from the term class's
    ``off_values``, ``one_sided``, ``score_grid``, ``score_directions`` and ``score_point``.

    Attributes:
        name: the effect's name (its class name).
        term: the term, with the tested parameters at their off-values.
        tested: names of the parameters tested at their off-values.
        one_sided: one-sided test (only for a single tested column).
        grid: settings of other parameters searched by the score test.
        directions: settings whose columns are tested jointly.
        point: where the derivatives are taken.
    """

    name: str
    term: AbstractTerm
    tested: tuple[str, ...]
    one_sided: bool
    grid: tuple[dict, ...]
    directions: tuple[dict, ...]
    point: dict

    @classmethod
    def of(cls, effect: type | AbstractTerm) -> "Candidate":
        """The candidate for a term class (built at its off-values) or a term instance (its
        tested parameters are set to their off-values; its other parameters are kept)."""
        kind = effect if isinstance(effect, type) else type(effect)
        if not (isinstance(kind, type) and issubclass(kind, AbstractTerm)):
            raise TypeError(f"a candidate effect must be a vfjax term, got {effect!r}")
        if not kind.off_values:
            raise ValueError(
                f"{kind.__name__} declares no off_values: the diagnosis needs the "
                "parameter values that switch it off"
            )
        term = kind(**kind.off_values) if isinstance(effect, type) else effect
        for name, value in kind.off_values.items():
            field = kind.parameters[name][0]
            term = eqx.tree_at(lambda t, f=field: getattr(t, f), term, jnp.asarray(float(value)))
        tested = tuple(kind.off_values)
        directions = tuple(kind.score_directions)
        return cls(
            name=kind.__name__,
            term=term,
            tested=tested,
            one_sided=bool(kind.one_sided) and len(tested) * len(directions) == 1,
            grid=tuple(kind.score_grid),
            directions=directions,
            point={n: float(kind.score_point.get(n, kind.off_values[n])) for n in tested},
        )

    @property
    def extra(self) -> tuple[str, ...]:
        """Parameters set by the grid or the directions (fitted in the refit too)."""
        names = []
        for d in self.grid + self.directions:
            names += [n for n in d if n not in self.tested and n not in names]
        return tuple(names)

    @property
    def dof(self) -> int:
        return len(self.tested) * len(self.directions)


def default_candidates(model) -> list[Candidate]:
    """`DEFAULT_CANDIDATES` that are absent from ``model`` (or present at their off-value)."""
    out = []
    for kind in DEFAULT_CANDIDATES:
        term = model.term(kind)
        if term is None:
            out.append(Candidate.of(kind))
        elif _is_off(term):
            out.append(Candidate.of(term))
    return out


def _is_off(term) -> bool:
    kind = type(term)
    return all(float(getattr(term, kind.parameters[n][0])) == v for n, v in kind.off_values.items())


@dataclasses.dataclass(frozen=True)
class EffectScore:
    """The score test of one candidate effect.

    Attributes:
        effect: the effect's name.
        parameters: the tested parameter names.
        statistic: LM statistic (chi-square scale; for one-sided tests z * |z|).
        dof: degrees of freedom.
        p_value: p-value (Bonferroni-corrected over the grid where one is searched).
        direction: sign of the one-step estimate (single column), else 0.
        one_sided: whether the test is one-sided.
        explained: share of the residual sum of squares that the effect's columns explain
            (after projection), a linearised measure of how much it could help.
        estimates: one-step (Gauss-Newton) estimates of the effect's parameters from the
            off-value: at the two grid settings with the largest statistics, then at the
            best setting of each quarter of the grid (refit starts spread over it; one
            estimate without a grid).
    """

    effect: str
    parameters: tuple
    statistic: float
    dof: int
    p_value: float
    direction: int
    one_sided: bool
    explained: float
    estimates: tuple

    @property
    def estimate(self) -> dict:
        """The one-step estimate at the best grid setting."""
        return self.estimates[0]


@dataclasses.dataclass(frozen=True)
class EffectRefit:
    """The quick refit with one candidate effect.

    Attributes:
        effect: the effect's name.
        result: the refit (`FitResult`; its model holds the effect).
        nmse: the error it reaches.
        fall: share of the current squared error it removes, 1 - nmse / nmse_before.
        values: the effect's fitted parameters.
        p_value: F test of the error fall against the control refit, on the effective
            number of independent frames (`effective_frames`).
    """

    effect: str
    result: FitResult
    nmse: float
    fall: float
    values: dict
    p_value: float


@dataclasses.dataclass(frozen=True)
class Diagnosis:
    """What `diagnose` found.

    Attributes:
        result: the fit that was diagnosed.
        recording_name: its recording's name.
        comparison: the measured-vs-fitted `Comparison`.
        scores: score tests by effect name.
        refits: quick refits by effect name (empty without refits).
        control: the same refit without any effect (None without refits): the error the
            fitted model itself reaches with the refit's search; falls are measured from the
            lower of its error and the fit's.
        ranking: effect names, best first.
        needed: effects that pass both criteria, best first.
        alpha: the family-wise significance level; ``level`` = alpha / number of candidates.
        min_fall: the share of the squared error a needed effect's refit must remove.
        noise_multiple: the noise floors' worth of NMSE it must remove.
        noise_nmse: the NMSE that measurement noise alone would leave (estimated from the
            GAW's frame-to-frame differences), a floor no model can beat.
        verdict: the conclusion in words.
    """

    result: FitResult
    recording_name: str
    comparison: Comparison
    scores: dict
    refits: dict
    control: FitResult | None
    ranking: list
    needed: list
    alpha: float
    level: float
    min_fall: float
    noise_multiple: float
    noise_nmse: float
    verdict: str

    @property
    def nmse_before(self) -> float:
        """The error the falls are measured from: the fit's, or the control refit's if lower."""
        return min(self.result.nmse, self.control.nmse) if self.control else self.result.nmse

    @property
    def best(self) -> str | None:
        """The effect to add (the top needed one), or None."""
        return self.needed[0] if self.needed else None

    @property
    def best_fit(self) -> FitResult | None:
        """The refit with the best needed effect, or None."""
        return self.refits.get(self.best).result if self.best in self.refits else None

    def table(self) -> list[dict]:
        """One row per candidate, in ranking order."""
        rows = []
        for rank, name in enumerate(self.ranking, 1):
            s = self.scores[name]
            f = self.refits.get(name)
            rows.append(
                {
                    "rank": rank,
                    "effect": name,
                    "statistic": s.statistic,
                    "dof": s.dof,
                    "p_value": s.p_value,
                    "one_sided": s.one_sided,
                    "nmse_after": f.nmse if f else None,
                    "fall": f.fall if f else None,
                    "refit_p_value": f.p_value if f else None,
                    "evidence": _evidence(s, f),
                    "significant": _evidence(s, f) < self.level,
                    "values": f.values if f else {},
                    "needed": name in self.needed,
                }
            )
        return rows


# ----------------------------------------------------------------------------- sensitivities
class _Sampler(eqx.Module):
    """Simulates a fitted GAW (clipped at 0) as the fit sampled it, padded to the length
    bucket (one compiled program per model structure and bucket)."""

    grid: SampledGrid
    n_out: int = eqx.field(static=True)
    n_rows: int = eqx.field(static=True)

    def gaw(self, model, shift):
        """The padded GAW; differentiable in forward mode (`jax.jacfwd`) only."""
        sim = simulate_frames(model, self.grid, shift, n_out=self.n_out, n_rows=self.n_rows)
        return jnp.maximum(sim.area, 0.0)


def _sampler(result: FitResult) -> _Sampler:
    return _Sampler(sampled_grid(result.sampling), *window_size(result.sampling))


@eqx.filter_jit
def _fitted_columns(sampler, model, names, shift):
    """The GAW and its derivatives: d/dlog(p) (d/dp where p = 0) and d/d(shift)."""
    values = jnp.stack([model.params()[n] for n in names])
    scale = jnp.where(values != 0.0, values, 1.0)

    def g(p, t):
        return sampler.gaw(model.set(**{n: p[i] for i, n in enumerate(names)}), t)

    jp, jt = jax.jacfwd(g, argnums=(0, 1))(values, shift)
    return g(values, shift), jnp.concatenate([jp * scale, jt[:, None]], axis=1)


@eqx.filter_jit
def _effect_columns(sampler, models, names, points, shift):
    """d GAW / d(tested parameters ``names``) for a batch of models, each at its row of
    ``points``."""

    def one(model, point):
        def g(p):
            return sampler.gaw(model.set(**{n: p[i] for i, n in enumerate(names)}), shift)

        return jax.jacfwd(g)(point)

    return jax.vmap(one)(models, points)


def _stack(models):
    return jax.tree.map(lambda *xs: jnp.stack(xs), *models)


# ------------------------------------------------------------------------------- statistics
def _hac(h: np.ndarray, bandwidth: int) -> np.ndarray:
    """Newey-West long-run covariance of the rows of h (n, k), Bartlett weights."""
    v = h.T @ h
    for lag in range(1, min(bandwidth, h.shape[0] - 1) + 1):
        g = h[lag:].T @ h[:-lag]
        v += (1.0 - lag / (bandwidth + 1.0)) * (g + g.T)
    return v


def _score(r, q, je, n_fitted, variance, bandwidth):
    """(u, V, LM, explained, one-step estimate) for the columns je against residual r."""
    me = je - q @ (q.T @ je)
    u = me.T @ r
    if variance == "hac":
        v = _hac(me * r[:, None], bandwidth)
    else:
        v = float(r @ r) / max(r.size - n_fitted, 1) * (me.T @ me)
    lm = float(u @ np.linalg.pinv(v) @ u)
    gram = me.T @ me
    step = np.linalg.lstsq(gram, u, rcond=None)[0]
    rr = float(r @ r)
    explained = float(u @ step) / rr if rr > 0 else 0.0
    return u, v, lm, explained, step


def score_tests(
    result: FitResult,
    recording: Recording,
    candidates: Sequence | None = None,
    *,
    variance: str = "hac",
) -> list[EffectScore]:
    """Score tests of the ``candidates`` (default: `default_candidates`) at ``result``.

    Arguments:
        result: a fit (`vfjax.fit`) of ``recording``.
        recording: the measured GAW.
        candidates: term classes, term instances or `Candidate` objects.
        variance: ``"hac"`` (autocorrelation-robust, default) or ``"iid"``.
    Returns the scores in the order of the candidates.
    """
    if variance not in ("hac", "iid"):
        raise ValueError(f"variance must be 'hac' or 'iid', got {variance!r}")
    cands = _as_candidates(result.model, candidates)
    sampler = _sampler(result)
    names = tuple(result.params)
    g0, jf = (
        np.asarray(a)[: recording.n_frames]
        for a in _fitted_columns(sampler, result.model, names, jnp.asarray(result.time_shift))
    )
    r = np.asarray(recording.area, dtype=float) - g0
    q, _ = np.linalg.qr(jf)
    bandwidth = _bandwidth(recording)
    columns = _candidate_columns(result, sampler, cands)
    return [
        _candidate_score(c, cols, r, q, jf.shape[1], variance, bandwidth)
        for c, cols in zip(cands, columns)
    ]


def _extended(model, cands):
    """``model`` with every candidate's term added (at its off-value), or None if several
    candidates' parameter names clash."""
    for c in cands:
        model = model.with_term(c.term)
    declared = [n for t in model.terms for n in t.parameters]
    return model if len(cands) < 2 or len(declared) == len(set(declared)) else None


def _candidate_columns(result, sampler, cands) -> list[np.ndarray]:
    """Each candidate's GAW sensitivities, (settings, frames, tested), one setting per
    grid point and direction (`Candidate.grid`, `Candidate.directions`).

    One compiled program serves all candidates: the fitted model extended by all of them,
    in one variant per candidate and setting, where that candidate sits at its setting and
    score point and the others at their off-values (where they change nothing)."""
    wide = _extended(result.model, cands)
    if wide is None:
        return [_candidate_columns(result, sampler, [c])[0] for c in cands]
    tested = tuple(dict.fromkeys(n for c in cands for n in c.tested))
    off = {n: float(type(c.term).off_values[n]) for c in cands for n in c.tested}
    variants, points, rows = [], [], []
    for c in cands:
        at = {**off, **c.point}
        settings = [{**g, **d} for g in c.grid for d in c.directions]
        rows.append(slice(len(variants), len(variants) + len(settings)))
        variants += [wide.set(**setting) for setting in settings]
        points += [[at[n] for n in tested]] * len(settings)
    cols = np.asarray(
        _effect_columns(
            sampler, _stack(variants), tested, jnp.asarray(points), jnp.asarray(result.time_shift)
        )
    )
    cols = cols[:, : result.sampling.n_frames]
    return [cols[r][:, :, [tested.index(n) for n in c.tested]] for c, r in zip(cands, rows)]


def _bandwidth(recording) -> int:
    """One glottal period in frames: the lag window of the robust variance and of
    `effective_frames` (a tenth of the frame rate if no f0 is found)."""
    from .descriptors import fundamental_frequency

    f0 = fundamental_frequency(recording.area, recording.fps)
    return max(1, round(recording.fps / f0)) if np.isfinite(f0) else 10


def _candidate_score(cand, cols, r, q, n_fitted, variance, bandwidth):
    n_dir = len(cand.directions)
    # (grid, directions, frames, tested) -> per grid point: (frames, directions * tested)
    cols = cols.reshape(len(cand.grid), n_dir, r.size, len(cand.tested))
    found = []
    for gi, setting in enumerate(cand.grid):
        je = np.concatenate([cols[gi, di] for di in range(n_dir)], axis=1)
        found.append((*_score(r, q, je, n_fitted, variance, bandwidth), setting))
    # estimates: the two best grid settings, then the best of each quarter of the grid (a
    # misfit far from the linear regime can put the truth anywhere on it: refit starts)
    cuts = np.array_split(np.arange(len(found)), min(4, len(found)))
    quarters = [max((found[i] for i in q), key=lambda f: f[2]) for q in cuts]
    found.sort(key=lambda f: -f[2])
    u, v, lm, explained, step, setting = found[0]
    chosen = found[:2] + [f for f in quarters if not any(f is g for g in found[:2])]
    estimates = tuple(_estimate(cand, f[4], f[5]) for f in chosen)
    if cand.one_sided:
        z = float(u[0] / math.sqrt(v[0, 0])) if v[0, 0] > 0 else 0.0
        statistic, p = z * abs(z), float(stats.norm.sf(z))
    else:
        statistic, p = lm, float(stats.chi2.sf(lm, cand.dof))
    p = min(1.0, p * len(cand.grid))
    direction = int(np.sign(step[0])) if step.size == 1 else 0
    return EffectScore(
        cand.name,
        cand.tested,
        statistic,
        cand.dof,
        p,
        direction,
        cand.one_sided,
        explained,
        estimates,
    )


def _estimate(cand, step, setting):
    """The one-step estimate as parameter values (a sine/cosine pair -> amplitude, phase)."""
    est = dict(setting)
    if len(cand.directions) == 2 and len(cand.tested) == 1:
        d0, d1 = cand.directions
        (phase_name,) = [n for n in d0 if n in d1] or [None]
        if phase_name is not None:
            # c0 sin(w t + p0) + c1 sin(w t + p1) with p1 = p0 + pi/2 is A sin(w t + p0 + psi)
            c0, c1 = float(step[0]), float(step[1])
            est[cand.tested[0]] = cand.point[cand.tested[0]] + math.hypot(c0, c1)
            est[phase_name] = _wrap(d0[phase_name] + math.atan2(c1, c0))
            return est
    for i, n in enumerate(cand.tested):
        est[n] = cand.point[n] + float(step[i * len(cand.directions)])
    for d in cand.directions[:1]:
        est.update({k: v for k, v in d.items() if k not in est})
    return est


def _wrap(angle):
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def _as_candidates(model, candidates):
    if candidates is None:
        return default_candidates(model)
    out = [c if isinstance(c, Candidate) else Candidate.of(c) for c in candidates]
    present = [
        c.name for c in out if model.has(type(c.term)) and not _is_off(model.term(type(c.term)))
    ]
    if present:
        raise ValueError(f"{present} already active in the fitted model: nothing to test")
    return out


# ----------------------------------------------------------------------------------- refits
def _starts(
    cand: Candidate, model, recording, score: EffectScore, n: int, anchor: dict | None = None
) -> list[dict]:
    """Starting values of the effect's parameters for the refit: just off the off-value (the
    current fit), then the one-step estimates (at the next-best grid settings, or scaled)
    and, for a candidate with a grid, a lattice over the grid and the phases; all clipped
    into the parameters' ranges.

    ``anchor`` (values of fitted parameters, e.g. `_anchor`'s) is a second base for the
    lattice: every other lattice point starts from it instead of the current fit. A fit made
    without the effect may have bent the fitted parameters far from where the effect needs
    them (a closure hold stretched to mimic a pressure modulation's missing closures), and
    from there the effect's basin is out of a small swarm's reach."""

    def _range(name):
        return search_range(model, name) or (-np.inf, np.inf, 0.1)

    def near_off(est):
        return {**est, **{t: cand.point[t] + 0.03 * _range(t)[2] for t in cand.tested}}

    ests = list(score.estimates)
    if len(cand.grid) > 1:
        # far from the linear regime the one-step estimates mislead: add a lattice over the
        # grid (four settings) and, for a sine/cosine pair, three phases, with the tested
        # parameters one range-scale step off
        phases = [k for k in cand.directions[0] if all(k in d for d in cand.directions)]
        lattice = [
            {
                **ests[0],
                **g,
                **{t: cand.point[t] + _range(t)[2] for t in cand.tested},
                **{k: _wrap(cand.directions[0][k] + a) for k in phases},
            }
            for g in (cand.grid[int(i)] for i in np.linspace(0, len(cand.grid) - 1, 4))
            for a in ((0.0, 2.1, -2.1) if phases else (0.0,))
        ]
        if anchor:
            lattice = [{**p, **anchor} if i % 2 else p for i, p in enumerate(lattice)]
        ests += lattice
        n += len(ests) - 1
    proposals = [near_off(ests[0]), ests[0]]
    guess = type(cand.term).guess(recording)
    if guess:  # values the data show directly (a closure duration) come second
        proposals.insert(1, {**ests[0], **guess})
    proposals += (
        ests[1:]
        if len(ests) > 1
        else [
            {
                **ests[0],
                **{t: cand.point[t] + f * (ests[0][t] - cand.point[t]) for t in cand.tested},
            }
            for f in (2.0, 0.5)
        ]
    )
    starts = []
    for s in proposals[:n]:
        s = dict(s)
        for name in cand.tested + cand.extra:
            low, high, scale = _range(name)
            value = s[name]
            if cand.one_sided and name in cand.tested:
                value = max(value, cand.point[name] + 1e-2 * scale)
            s[name] = float(np.clip(value, low, high))
        starts.append(s)
    return starts


def refit_with(
    result: FitResult,
    recording: Recording,
    candidate=None,
    starts: Sequence[dict] = ({},),
    *,
    iterations: int = 30,
    swarm_size: int = 24,
    lm_steps: int = 30,
    box: float = 1.6,
    anchor: dict | None = None,
) -> FitResult:
    """Refit ``result``'s parameters plus the candidate's, from each of ``starts`` (values of
    the candidate's parameters, and of fitted ones where given), as one batch
    (`vfjax.fit_many`); returns the best refit. Without a candidate: the same refit of the
    fitted model alone (the control).

    Each start is particle 0 of a small swarm (``swarm_size`` particles, ``iterations``
    iterations) that searches the effect's parameters over their range (`search_range`)
    and the fitted ones within a factor ``box`` of their current values, and of their
    ``anchor`` values if given (e.g. the fit's starting model: an effect that changes the
    dynamics, such as the flow separation, can move K and C_f far from a fit made without
    it) and of the starts' values; then LM. `refit_each` runs several candidates' refits as
    one batch.
    """
    return refit_each(
        result,
        recording,
        [(candidate, starts)],
        iterations=iterations,
        swarm_size=swarm_size,
        lm_steps=lm_steps,
        box=box,
        anchor=anchor,
    )[0]


def refit_each(
    result: FitResult,
    recording: Recording,
    jobs: Sequence[tuple],
    *,
    iterations: int = 30,
    swarm_size: int = 24,
    lm_steps: int = 30,
    box: float = 1.6,
    anchor: dict | None = None,
    warmup: float | None = None,
) -> list[FitResult]:
    """`refit_with` for several candidates at once: ``jobs`` is a list of ``(candidate or
    None, starts)``; returns the best refit of each job.

    All jobs run as one `vfjax.fit_many` batch, so one compiled program serves them all:
    every start simulates the fitted model extended by all the jobs' candidates, those of
    other jobs held at their off-values (where they change nothing). Each returned fit's
    model carries its own candidate only. If the candidates' parameter names clash, each job
    runs as its own batch. ``warmup`` (s) defaults to the fit's.
    """
    cands = [
        None if c is None else c if isinstance(c, Candidate) else Candidate.of(c) for c, _ in jobs
    ]
    names = tuple(result.params)
    own = [names + (() if c is None else c.tested + c.extra) for c in cands]
    wide = _extended(result.model, [c for c in cands if c is not None])
    if wide is None:
        return [
            refit_each(
                result,
                recording,
                [job],
                iterations=iterations,
                swarm_size=swarm_size,
                lm_steps=lm_steps,
                box=box,
                anchor=anchor,
                warmup=warmup,
            )[0]
            for job in jobs
        ]
    added = [type(t) for t in wide.terms if not result.model.has(type(t))]
    union = tuple(dict.fromkeys(n for o in own for n in o))
    models, holds, owner = [], [], []
    for j, (_, starts) in enumerate(jobs):
        for s in starts:
            models.append(wide.set(**{k: v for k, v in s.items() if k in own[j]}))
            holds.append(tuple(n for n in union if n not in own[j]))
            owner.append(j)
    anchor = {n: v for n, v in (anchor or {}).items() if n in result.params and v > 0}
    bounds = {}  # a factor box around the current values, the anchor's and every start's
    for n, v in result.params.items():
        if v > 0 and search_range(wide, n) is None:
            given = [v, anchor.get(n, v)] + [s[n] for _, ss in jobs for s in ss if s.get(n, 0) > 0]
            bounds[n] = (min(given) / box, max(given) * box)
    fits = fit_many(
        models,
        [recording] * len(models),
        params=union,
        swarm=Swarm(size=swarm_size, iterations=iterations),
        polish=Polish(max_steps=lm_steps),
        warmup=result.sampling.warmup if warmup is None else warmup,
        substeps=result.sampling.substeps,
        bounds=bounds,
        hold=holds,
    )
    best = []
    for j, c in enumerate(cands):
        mine = [f for f, o in zip(fits, owner) if o == j]
        fit = min(mine, key=_error)
        # the other jobs' candidates sit at their off-values: drop them from the model
        dormant = [k for k in added if c is None or k is not type(c.term)]
        model = fit.model.without(*dormant) if dormant else fit.model
        best.append(dataclasses.replace(fit, model=model))
    return best


def _anchor(result: FitResult, recording: Recording) -> dict:
    """The fitted parameters' values in the recording's starting model (`initial_model`),
    a second centre for the refits' search; empty if there is none."""
    try:
        start = initial_model(recording).params()
    except (ValueError, KeyError):
        return {}
    return {n: float(start[n]) for n in result.params if n in start}


def effective_frames(residual: np.ndarray, bandwidth: int) -> float:
    """Frames' worth of independent information in a correlated residual: n over the
    long-run variance ratio 1 + 2 sum_l w_l rho_l (Bartlett weights, lags up to
    ``bandwidth``), kept within [n / (bandwidth + 1), n]."""
    r = np.asarray(residual, dtype=float) - np.mean(residual)
    n, c0 = r.size, float(r @ r)
    if c0 == 0:
        return float(n)
    ratio = 1.0 + 2.0 * sum(
        (1.0 - lag / (bandwidth + 1.0)) * float(r[lag:] @ r[:-lag]) / c0
        for lag in range(1, min(bandwidth, n - 1) + 1)
    )
    return float(np.clip(n / max(ratio, 1e-12), n / (bandwidth + 1.0), n))


def _refit_p_value(sse0, sse1, n_eff, n_fitted, n_added):
    """F test of the refit's error fall, on ``n_eff`` effective frames."""
    dof = n_eff - n_fitted - n_added
    if sse1 <= 0 or dof <= 0:
        return 0.0 if sse1 < sse0 else 1.0
    f = max(sse0 - sse1, 0.0) / n_added / (sse1 / dof)
    return float(stats.f.sf(f, n_added, dof))


# -------------------------------------------------------------------------------- diagnosis
def diagnose(
    result: FitResult,
    recording: Recording,
    candidates: Sequence | None = None,
    *,
    alpha: float = 0.01,
    min_fall: float = 0.2,
    noise_multiple: float = 3.0,
    refit: bool = True,
    starts: int = 3,
    iterations: int = 30,
    confirm: tuple[int, int] | None = CONFIRM,
    variance: str = "hac",
    progress: bool = False,
) -> Diagnosis:
    """Find the effect the fitted model misses (see the module's docstring).

    Arguments:
        result: a fit (`vfjax.fit`) of ``recording``.
        recording: the measured GAW.
        candidates: term classes, term instances or `Candidate` objects (default: the
            catalogue, `default_candidates`).
        alpha: family-wise significance level (Bonferroni over the candidates and over the
            two tests, score and refit).
        min_fall: share of the squared error a needed effect's refit must remove.
        noise_multiple: ... and how many noise floors' worth of NMSE (`Diagnosis.noise_nmse`)
            it must remove at least.
        refit: run the quick refits (and the control refit without any effect).
        starts: starting points per refit (batched).
        iterations: PSO iterations of each refit's small swarms.
        confirm: (particles, iterations) of a second, larger refit of the leading candidate
            and of the control, from their quick refits and the anchor: a candidate with
            several interacting parameters (a modulation's depth, frequency and phase) has
            narrow basins that a quick refit may miss. For a leader whose quick refit removes
            ``min_fall`` of the error, the swarm grows with its parameters
            (`confirm_swarm`). None: quick refits only.
        variance: ``"hac"`` (default) or ``"iid"``, see `score_tests`.
        progress: print one line per refit.
    """
    if not 0 < alpha < 1:
        raise ValueError(f"alpha must lie in (0, 1), got {alpha}")
    if not 0 <= min_fall < 1:
        raise ValueError(f"min_fall must lie in [0, 1), got {min_fall}")
    if confirm is not None and (
        len(confirm) != 2 or any(not isinstance(c, int) or c < 1 for c in confirm)
    ):
        raise ValueError(
            f"confirm must be (particles, iterations), positive integers, or None; got {confirm!r}"
        )
    cands = _as_candidates(result.model, candidates)
    if not cands:
        raise ValueError("no candidate effect to test: every one is already in the model")
    comparison = compare(result, recording)
    scores = score_tests(result, recording, cands, variance=variance)
    by_name = {s.effect: s for s in scores}
    level = alpha / len(cands)
    refits, control, reference = {}, None, result.nmse
    bandwidth = _bandwidth(recording)
    sse_scale = float(np.sum(np.square(recording.area)))
    if refit:
        anchor = _anchor(result, recording)
        anchored = [anchor] if anchor else []  # no anchor: no second, identical start
        jobs = [(None, [{}] + anchored)]
        for cand, score in zip(cands, scores):
            model = result.model.with_term(cand.term)
            begin = _starts(cand, model, recording, score, starts, anchor)
            jobs.append((cand, begin + [{**begin[0], **a} for a in anchored]))
        control, *fitted_each = refit_each(
            result, recording, jobs, iterations=iterations, anchor=anchor
        )
        if confirm is not None:
            control, fitted_each = _confirm(
                result, recording, jobs, control, fitted_each, confirm, anchor, iterations, min_fall
            )
        reference = min(result.nmse, control.nmse)
        if progress:
            print(f"control (no effect): NMSE {result.nmse:.4g} -> {control.nmse:.4g}")
        before = result if result.nmse <= control.nmse else control
        n_eff = effective_frames(recording.area - before.fitted_gaw(recording), bandwidth)
        for cand, score, fitted in zip(cands, scores, fitted_each):
            values = {n: fitted.params[n] for n in cand.tested + cand.extra}
            fall = 1.0 - fitted.nmse / reference if reference > 0 else 0.0
            p = _refit_p_value(
                reference * sse_scale,
                fitted.nmse * sse_scale,
                n_eff,
                len(result.params) + 1,
                len(values),
            )
            refits[cand.name] = EffectRefit(cand.name, fitted, fitted.nmse, fall, values, p)
            if progress:
                print(
                    f"{cand.name}: score p = {score.p_value:.2g}, NMSE {reference:.4g} -> "
                    f"{fitted.nmse:.4g} (refit p = {p:.2g})"
                )
        ranking = sorted(by_name, key=lambda n: (refits[n].nmse, by_name[n].p_value))
    else:
        ranking = sorted(by_name, key=lambda n: (by_name[n].p_value, -by_name[n].statistic))
    # the noise floor, from the residual of the best model at hand (a misfit with sharp
    # features inflates the estimate); no floor can exceed that model's own error
    fits = [result] + ([control] if control else []) + [f.result for f in refits.values()]
    best_fit = min(fits, key=_error)
    noise = noise_level(recording.area, best_fit.fitted_gaw(recording))
    noise_nmse = min(recording.n_frames * noise**2 / sse_scale, best_fit.nmse)

    def is_needed(n):
        if _evidence(by_name[n], refits.get(n)) >= level:
            return False
        if not refits:
            return True
        f = refits[n]
        # it must remove a share of the error, and several noise floors' worth of it: a few
        # extra parameters fitted to noise and cycle-to-cycle jitter remove less
        return f.fall >= min_fall and reference - f.nmse >= noise_multiple * noise_nmse

    needed = [n for n in ranking if is_needed(n)]
    diag = Diagnosis(
        result,
        recording.name,
        comparison,
        by_name,
        refits,
        control,
        ranking,
        needed,
        alpha,
        level,
        min_fall,
        noise_multiple,
        noise_nmse,
        "",
    )
    return dataclasses.replace(diag, verdict=_verdict(diag))


def confirm_swarm(confirm: tuple[int, int], n_params: int, scale: bool = True) -> tuple[int, int]:
    """The confirming refit's (particles, iterations) for a candidate of ``n_params``
    parameters: ``confirm`` for one, and per further parameter twice the particles and a
    quarter more iterations (a swarm must cover a larger box, and the basins of interacting
    parameters, such as a modulation's frequency and phase, are narrow). ``scale=False``:
    ``confirm`` itself."""
    particles, iterations = confirm
    extra = max(n_params - 1, 0) if scale else 0
    return particles * 2**extra, int(round(iterations * (1 + extra / 4)))


def _confirm(result, recording, jobs, control, fitted, confirm, anchor, iterations, min_fall):
    """Refit the leading candidate (the lowest quick-refit error) and the control again with
    a larger swarm, from their quick refits and from the jobs' anchored starts; keep each
    one's better fit. The control gets the same search as the candidate, so that the fall
    it is measured against is not the product of a bigger search alone. If the leader's
    quick refit removes ``min_fall`` of the error (an effect likely to be reported, whose
    parameters then matter), the swarm grows with its parameter count (`confirm_swarm`).

    A candidate that needs a longer warm-up than the fit's (its term's ``min_warmup``: a slow
    modulation, whose history is in the state at the first frame) is first refitted again at
    that warm-up from all its quick starts, and so is the control; the larger refits then
    start from those."""
    top = min(range(len(fitted)), key=lambda i: _error(fitted[i]))
    (_, control_starts), (cand, cand_starts) = jobs[0], jobs[1 + top]
    reference = min(_error(result), _error(control))
    matters = _error(fitted[top]) <= (1.0 - min_fall) * reference
    swarm_size, deep_iterations = confirm_swarm(confirm, len(cand.tested + cand.extra), matters)
    warmup = max(result.sampling.warmup, float(type(cand.term).min_warmup))
    quick = (control, fitted[top])
    if warmup > result.sampling.warmup:
        quick = refit_each(
            result,
            recording,
            [jobs[0], jobs[1 + top]],
            iterations=iterations,
            anchor=anchor,
            warmup=warmup,
        )

    def from_anchor(starts):
        return [s for s in starts if anchor and all(s.get(k) == v for k, v in anchor.items())]

    deep = [
        (None, [dict(quick[0].params)] + from_anchor(control_starts)),
        (cand, [dict(quick[1].params)] + (from_anchor(cand_starts) or cand_starts[-1:])),
    ]
    c, f = refit_each(
        result,
        recording,
        deep,
        iterations=deep_iterations,
        swarm_size=swarm_size,
        anchor=anchor,
        warmup=warmup,
    )
    fitted = list(fitted)
    fitted[top] = min(fitted[top], quick[1], f, key=_error)
    return min(control, quick[0], c, key=_error), fitted


def _error(fit: FitResult) -> float:
    """A fit's NMSE for ranking (a non-finite one ranks last)."""
    return fit.nmse if np.isfinite(fit.nmse) else np.inf


def _evidence(score: EffectScore, refit: "EffectRefit | None") -> float:
    """Combined p-value: the smaller of the score test's and the refit's, doubled."""
    if refit is None:
        return score.p_value
    return min(1.0, 2.0 * min(score.p_value, refit.p_value))


def _verdict(d: Diagnosis) -> str:
    before = d.nmse_before
    floor = f"noise floor about {d.noise_nmse:.3%}"
    lines = []
    if d.control is not None and d.control.nmse < 0.8 * d.result.nmse:
        lines.append(
            f"The fit was not the best the model can do: a refit without any effect "
            f"reaches NMSE {d.control.nmse:.3%} (was {d.result.nmse:.3%})"
        )
    if d.best is not None:
        f = d.refits.get(d.best)
        text = f"{d.best} is missing (evidence p = {_evidence(d.scores[d.best], f):.2g})"
        if f is not None:
            values = ", ".join(f"{k} = {v:.4g}" for k, v in f.values.items())
            text += (
                f": adding it lowers the NMSE from {before:.3%} to {f.nmse:.3%} "
                f"({f.fall:.0%} of the squared error; {values})"
            )
            if f.nmse > 2.0 * d.noise_nmse and f.nmse > 0.002:
                text += (
                    f". The error left is above the noise ({floor}): something else is "
                    "still missing; diagnose the extended fit for a second round"
                )
        lines.append(text)
        return ". ".join(lines) + "."
    significant = [n for n in d.ranking if _evidence(d.scores[n], d.refits.get(n)) < d.level]
    f = d.refits.get(significant[0]) if significant else None
    if before <= 2.0 * d.noise_nmse:
        lines.append(
            f"No effect is needed: the NMSE {before:.3%} is at the noise level "
            f"({floor}) and no candidate removes {d.min_fall:.0%} of it"
        )
    elif significant and f is None:
        lines.append(
            f"{significant[0]} is significant (score test p = "
            f"{d.scores[significant[0]].p_value:.2g}); run the refits to see how "
            "much of the error it removes"
        )
    elif significant:
        why = (
            f"removes only {f.fall:.0%} of the squared error"
            if f.fall < d.min_fall
            else f"removes only {before - f.nmse:.3%} of NMSE, less than {d.noise_multiple:g} "
            f"noise floors ({d.noise_multiple * d.noise_nmse:.3%}): no more than fitting "
            "noise and cycle-to-cycle variability would"
        )
        lines.append(
            f"No catalogue effect is needed: {significant[0]} is statistically "
            f"detectable (p = {_evidence(d.scores[significant[0]], f):.2g}) but {why} "
            f"(NMSE {before:.3%}, {floor})"
        )
    else:
        lines.append(
            f"No candidate effect is significant (NMSE {before:.3%}, {floor}): the "
            "misfit left is not one the catalogue describes"
        )
    failures = d.comparison.failures()
    if failures and before > 2.0 * d.noise_nmse:
        lines.append("Where the model fails: " + "; ".join(failures[:3]))
    return ". ".join(lines) + "."


def extend(result: FitResult, recording: Recording, effect, params=None, **fit_kwargs):
    """Add ``effect`` to the fitted model and refit, warm-started from the current fit.

    Arguments:
        result: the current fit.
        recording: its recording.
        effect: the term to add, with its starting values (e.g. ``GlottalGap()``, or a
            diagnosis's ``refits[name].result.model.term(GlottalGap)``).
        params: the effect's parameters to fit (default: all of them).
        fit_kwargs: passed to `vfjax.fit` (default: 40 swarm iterations, no progress bar, the
            current fit's substeps, and its warm-up or the effect's ``min_warmup`` if longer).
    Returns the new `FitResult`; its model holds the effect.
    """

    model = result.model.with_effect(effect)
    names = tuple(result.params) + tuple(params or type(effect).parameters)
    kwargs = {
        "swarm": Swarm(iterations=40),
        "progress": False,
        "substeps": result.sampling.substeps,
        "warmup": max(result.sampling.warmup, default_warmup(model)),
        **fit_kwargs,
    }
    return fit(model, recording, params=names, **kwargs)
