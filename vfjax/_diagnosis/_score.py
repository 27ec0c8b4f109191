"""The score (Lagrange-multiplier) test of each candidate effect, from the current fit alone."""

import dataclasses
import math
from collections.abc import Sequence
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from .._fit import FitResult
from ..descriptors import fundamental_frequency
from ..integrator import SampledGrid, sampled_grid, simulate_frames, window_size
from ..recording import Recording
from ._candidates import Candidate, as_candidates, extended


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
def _columns(sampler, model, names, shift, variants, tested, points):
    """The fitted GAW, its derivatives d/dlog(p) of the fitted parameters ``names`` (d/dp
    where p = 0) and d/d(shift), and, for each of the models ``variants`` (stacked), the
    derivatives d GAW / d(``tested``) at its row of ``points``. One program for the whole
    score test."""
    values = jnp.stack([model.params()[n] for n in names])
    scale = jnp.where(values != 0.0, values, 1.0)

    def g(p, t):
        return sampler.gaw(model.set(**{n: p[i] for i, n in enumerate(names)}), t)

    jp, jt = jax.jacfwd(g, argnums=(0, 1))(values, shift)

    def one(variant, point):
        def ge(p):
            return sampler.gaw(variant.set(**{n: p[i] for i, n in enumerate(tested)}), shift)

        return jax.jacfwd(ge)(point)

    effects = jax.vmap(one)(variants, points)
    return g(values, shift), jnp.concatenate([jp * scale, jt[:, None]], axis=1), effects


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
    cands = as_candidates(result.model, candidates)
    g0, jf, columns = sensitivities(result, cands)
    r = np.asarray(recording.area, dtype=float) - g0
    q, _ = np.linalg.qr(jf)
    bandwidth = period_frames(recording)
    return [
        _candidate_score(c, cols, r, q, jf.shape[1], variance, bandwidth)
        for c, cols in zip(cands, columns)
    ]


def sensitivities(result: FitResult, cands: Sequence[Candidate]):
    """The fitted GAW (frames,), its derivatives in the fitted parameters and the time shift
    (frames, fitted + 1) and each candidate's derivatives (settings, frames, tested), one
    setting per grid point and direction, over the recording's frames.

    One compiled program (`_columns`) serves them all, through the fitted model extended by
    every candidate (`_candidate_jobs`); candidates whose parameter names clash run one
    program call each."""
    n = result.sampling.n_frames
    together = _candidate_jobs(result.model, cands)
    if together is not None:
        groups = [(list(cands), together)]
    else:
        groups = [([c], _candidate_jobs(result.model, [c])) for c in cands]
    columns = []
    for group, jobs in groups:
        g0, jf, cols = (
            np.asarray(a)[..., :n, :] if a.ndim > 1 else np.asarray(a)[:n]
            for a in _columns(
                _sampler(result),
                result.model,
                tuple(result.params),
                jnp.asarray(result.time_shift),
                _stack(jobs.variants),
                jobs.tested,
                jnp.asarray(jobs.points),
            )
        )
        columns += [
            cols[rows][:, :, [jobs.tested.index(t) for t in c.tested]]
            for c, rows in zip(group, jobs.rows)
        ]
    return g0, jf, columns


class _Jobs(NamedTuple):
    variants: list  # models, one per candidate and setting
    tested: tuple  # the tested parameters of all candidates
    points: list  # per variant, the values of ``tested`` where the derivatives are taken
    rows: list  # per candidate, its variants (a slice)


def _candidate_jobs(model, cands) -> _Jobs | None:
    """Each candidate's sensitivity jobs: one variant of the model per grid point and
    direction (`Candidate.grid`, `Candidate.directions`).

    One compiled program serves all candidates: the fitted model extended by all of them,
    in one variant per candidate and setting, where that candidate sits at its setting and
    score point and the others at their off-values (where they change nothing). None if the
    candidates' parameter names clash (`extended`)."""
    wide = extended(model, cands)
    if wide is None:
        return None
    tested = tuple(dict.fromkeys(n for c in cands for n in c.tested))
    off = {n: float(type(c.term).off_values[n]) for c in cands for n in c.tested}
    variants, points, rows = [], [], []
    for c in cands:
        at = {**off, **c.point}
        settings = [{**g, **d} for g in c.grid for d in c.directions]
        rows.append(slice(len(variants), len(variants) + len(settings)))
        variants += [wide.set(**setting) for setting in settings]
        points += [[at[n] for n in tested]] * len(settings)
    return _Jobs(variants, tested, points, rows)


def period_frames(recording) -> int:
    """One glottal period in frames: the lag window of the robust variance (a tenth of the
    frame rate if no f0 is found)."""
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
            est[phase_name] = wrap_angle(d0[phase_name] + math.atan2(c1, c0))
            return est
    for i, n in enumerate(cand.tested):
        est[n] = cand.point[n] + float(step[i * len(cand.directions)])
    for d in cand.directions[:1]:
        est.update({k: v for k, v in d.items() if k not in est})
    return est


def wrap_angle(angle):
    return (angle + math.pi) % (2.0 * math.pi) - math.pi
