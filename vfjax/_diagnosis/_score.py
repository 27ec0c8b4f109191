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
from .._fit._engine import stack_strong
from .._integrate import SampledGrid, sampled_grid, simulate_frames, window_size
from .._programs import program
from ..descriptors import fundamental_frequency
from ..recording import Recording
from ._candidates import Candidate, as_candidates, extended, wrap_angle


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


@program
def _columns(sampler, names, tested, models, points, tangents):
    """GAWs and their derivatives, one forward-mode simulation per job, all jobs side by side
    (one vmapped jvp: one copy of the simulator in the program, whatever the candidates).

    Job j simulates ``models[j]`` with ``tested`` at ``points[j]`` and returns its GAW and
    the derivative along ``tangents[j]``, a direction in (``names``, ``tested``, time shift).
    Returns (jobs, frames) GAWs and (jobs, frames) derivatives."""
    n_names, n_tested = len(names), len(tested)

    def gaw(z, model):
        values = {n: z[i] for i, n in enumerate(names)}
        values.update({n: z[n_names + i] for i, n in enumerate(tested)})
        return sampler.gaw(model.set(**values), z[n_names + n_tested])

    def one(model, z, dz):
        return jax.jvp(lambda y: gaw(y, model), (z,), (dz,))

    return jax.vmap(one)(models, points, tangents)


def _stack(models):
    """The models' leaves stacked on the host (`stack_strong`: one program however the
    models were made, and no small program per batch size)."""
    return jax.tree.map(stack_strong, *models)


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
    (frames, fitted + 1; d/dlog(p), or d/dp where p = 0) and each candidate's derivatives
    (settings, frames, tested), one setting per grid point and direction, over the
    recording's frames.

    One compiled program (`_columns`) serves them all, through the fitted model extended by
    every candidate (`_candidate_jobs`): the fitted parameters' derivatives with every
    candidate off (where they change nothing), each candidate's at its settings with the
    others off. Candidates whose parameter names clash run one program call each."""
    n = result.sampling.n_frames
    together = _candidate_jobs(result.model, cands)
    if together is not None:
        groups = [(list(cands), together)]
    else:
        groups = [([c], _candidate_jobs(result.model, [c])) for c in cands]
    names = tuple(result.params)
    fitted = np.array([float(result.model.params()[n]) for n in names])
    scale = np.where(fitted != 0.0, fitted, 1.0)
    columns = []
    for group, jobs in groups:
        width = len(names) + len(jobs.tested) + 1
        basis = np.eye(width)
        # jobs: the fitted parameters and the shift with every candidate off, then each
        # setting's derivatives along its candidate's tested parameters
        models = [jobs.base] * (len(names) + 1)
        points = [list(fitted) + jobs.off + [result.time_shift]] * (len(names) + 1)
        tangents = [basis[i] for i in range(len(names))] + [basis[-1]]
        for c, rows in zip(group, jobs.rows):
            for v in range(rows.start, rows.stop):
                for t in c.tested:
                    models.append(jobs.variants[v])
                    points.append(list(fitted) + list(jobs.points[v]) + [result.time_shift])
                    tangents.append(basis[len(names) + jobs.tested.index(t)])
        gaws, derivatives = (
            np.asarray(a)[:, :n]
            for a in _columns(
                _sampler(result),
                names,
                jobs.tested,
                _stack(models),
                np.asarray(points, dtype=float),
                np.stack(tangents),
            )
        )
        g0 = gaws[0]
        jf = derivatives[: len(names) + 1].T * np.append(scale, 1.0)
        k = len(names) + 1
        for c, rows in zip(group, jobs.rows):
            m = len(c.tested)
            count = rows.stop - rows.start
            cols = derivatives[k : k + count * m].reshape(count, m, n)
            columns.append(cols.transpose(0, 2, 1))
            k += count * m
    return g0, jf, columns


class _Jobs(NamedTuple):
    base: object  # the extended model with every candidate off
    off: list  # the values of ``tested`` that switch every candidate off
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
    return _Jobs(wide.set(**off), [off[n] for n in tested], variants, tested, points, rows)


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
