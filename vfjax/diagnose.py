"""Which physical effect is missing? Score (Lagrange-multiplier) tests from a fit.

At the fitted parameters, each candidate effect is added at its off-value. The residual r
(measured minus fitted GAW) is tested against the GAW's sensitivities to the effect's
parameters, with the sensitivities to the fitted parameters (and the time shift) projected
out: with J_f the fitted columns, M = I - J_f (J_f' J_f)^-1 J_f' and J_e the effect's,

    u = J_e' M r,    V = s² J_e' M J_e,    s² = r'r / (n - p),    LM = u' V^-1 u,

asymptotically chi-square with as many degrees of freedom as the effect has parameters. An
effect whose off-value is a boundary (a gap area, a delay, a strength >= 0) gets the one-sided
test z = u / sqrt(V). The pressure modulation's frequency and phase do not exist at zero
depth: its test takes the sine and cosine columns at each frequency of a grid (2 degrees of
freedom) and the largest statistic, Bonferroni-corrected over the grid. Effects are ranked by
p-value; ``alpha`` (corrected for the number of effects) decides "significant", so that "no
effect is needed" is a possible answer.

Caveat: the test assumes independent residuals. Cycle-to-cycle variability makes them
correlated on real data, which inflates the statistics; a quick refit with each candidate
(`vfjax.fit`) gives the error each would actually reach.
"""

import dataclasses
import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats

from .fit import FitResult
from .integrator import simulate
from .recording import Recording
from .terms.effects import CubicStiffness, GlottalGap, MucosalDelay, PressureModulation
from .terms.paper import ClosureHold, FlowSeparation

#: Modulation frequencies tried by the pressure-modulation test (Hz).
MODULATION_GRID = tuple(float(f) for f in range(2, 21))


@dataclasses.dataclass(frozen=True)
class EffectScore:
    """The score test of one candidate effect.

    Attributes:
        effect: the effect's class name.
        parameters: the tested parameter names.
        statistic: LM statistic (chi-square scale; for one-sided tests z² with the sign kept
            in ``direction``).
        dof: degrees of freedom.
        p_value: (Bonferroni-corrected within the effect where a grid is searched).
        direction: +1 if the data ask for a positive parameter, -1 for negative (1-parameter
            tests), 0 otherwise.
        one_sided: whether the test is one-sided.
        explained: share of the residual sum of squares the effect's direction explains.
        detail: extra information (e.g. the best modulation frequency).
    """

    effect: str
    parameters: tuple
    statistic: float
    dof: int
    p_value: float
    direction: int
    one_sided: bool
    explained: float
    detail: dict


def _candidates(model):
    """(label, model with the effect at its off-value, parameter names, evaluation point,
    one-sided) for each catalogue effect not already active in the model."""
    out = []
    if not model.has(GlottalGap):
        out.append(("GlottalGap", model.with_effect(GlottalGap()), ("a_gap",), (0.0,), True))
    if not model.has(CubicStiffness):
        out.append(("CubicStiffness", model.with_effect(CubicStiffness()), ("eta",), (0.0,),
                    False))  # fmt: skip
    if not model.has(MucosalDelay):
        # the delay's derivative is one-sided at 0: evaluate just above it
        out.append(("MucosalDelay", model.with_effect(MucosalDelay()), ("tau",), (1e-9,), True))
    if not model.has(FlowSeparation):
        m = model.with_effect(FlowSeparation(fs_strength=0.0))
        out.append(("FlowSeparation", m, ("fs_strength",), (0.0,), True))
    elif float(model.params()["fs_strength"]) == 0.0:
        out.append(("FlowSeparation", model, ("fs_strength",), (0.0,), True))
    if not model.has(ClosureHold):
        out.append(("ClosureHold", model.with_effect(ClosureHold(t_c=0.0)), ("t_c",), (0.0,),
                    True))  # fmt: skip
    return out


def _jacobian(model, result: FitResult, recording, names, point, extra_names):
    """GAW (px, clipped at 0) and its Jacobian: columns d/dlog(p) of the fitted parameters,
    d/d(shift) and d/d(extra) at ``point``."""
    s = result.settings
    fitted = list(result.params)
    base = {n: float(model.params()[n]) for n in fitted}

    def gaw(phi):
        values = {n: base[n] * jnp.exp(phi[i]) for i, n in enumerate(fitted)}
        values.update({n: phi[len(fitted) + 1 + j] for j, n in enumerate(extra_names)})
        sim = simulate(model.set(**values), recording.fps, recording.n_frames,
                       substeps=s["substeps"], t_start=s["warmup"],
                       time_shift=result.time_shift + phi[len(fitted)],
                       max_time_shift=s["max_time_shift"] + 1e-3)  # fmt: skip
        return jnp.maximum(sim.area, 0.0)

    phi0 = jnp.concatenate([jnp.zeros(len(fitted) + 1), jnp.asarray(point, dtype=float)])
    return _gaw_and_jac(gaw, phi0)


@eqx.filter_jit
def _gaw_and_jac(gaw, phi0):
    return gaw(phi0), jax.jacfwd(gaw)(phi0)


def _score(r, jf, je, dof_fitted):
    n = r.size
    q, _ = np.linalg.qr(jf)
    me = je - q @ (q.T @ je)
    s2 = float(r @ r) / max(n - dof_fitted, 1)
    u = me.T @ r
    v = s2 * (me.T @ me)
    v_inv = np.linalg.pinv(v)
    lm = float(u @ v_inv @ u)
    explained = lm * s2 / float(r @ r) if float(r @ r) > 0 else 0.0
    return u, v, lm, explained


def score_tests(
    result: FitResult,
    recording: Recording,
    alpha: float = 0.01,
    effects: tuple[str, ...] | None = None,
) -> tuple[list[EffectScore], float]:
    """Score tests of every catalogue effect absent from ``result.model`` (or only those
    named in ``effects``).

    Returns the scores ranked by p-value, and the per-effect significance level
    (``alpha`` over the number of effects tested).
    """
    model = result.model
    measured = np.asarray(recording.area, dtype=float)
    n_fit = len(result.params) + 1
    scores = []
    for label, m, names, point, one_sided in _candidates(model):
        if effects is not None and label not in effects:
            continue
        g, jac = (np.asarray(a) for a in _jacobian(m, result, recording, result.params, point,
                                                  names))  # fmt: skip
        r = measured - g
        u, v, lm, explained = _score(r, jac[:, :n_fit], jac[:, n_fit:], n_fit)
        if one_sided:
            z = float(u[0] / math.sqrt(v[0, 0])) if v[0, 0] > 0 else 0.0
            p = float(stats.norm.sf(z))
            scores.append(EffectScore(label, names, z * abs(z), 1, p, int(np.sign(z)), True,
                                      explained, {}))  # fmt: skip
        else:
            p = float(stats.chi2.sf(lm, len(names)))
            scores.append(EffectScore(label, names, lm, len(names), p, int(np.sign(u[0])),
                                      False, explained, {}))  # fmt: skip
    if not model.has(PressureModulation) and (effects is None or "PressureModulation" in effects):
        scores.append(_modulation_score(model, result, recording, measured, n_fit))
    scores.sort(key=lambda s: (s.p_value, -s.statistic))
    return scores, alpha / max(len(scores), 1)


def _modulation_score(model, result, recording, measured, n_fit):
    best = None
    for f in MODULATION_GRID:
        cols = []
        for phase in (0.0, 0.5 * math.pi):
            m = model.with_effect(PressureModulation(a_pm=0.0, f_m=f, phi=phase))
            g, jac = (np.asarray(a) for a in _jacobian(m, result, recording, result.params,
                                                      (0.0,), ("a_pm",)))  # fmt: skip
            cols.append(jac[:, -1])
            jf = jac[:, :n_fit]
        r = measured - g
        u, v, lm, explained = _score(r, jf, np.stack(cols, axis=1), n_fit)
        if best is None or lm > best[0]:
            best = (lm, explained, f, math.atan2(u[1], u[0]))
    lm, explained, f, phase = best
    p = min(1.0, float(stats.chi2.sf(lm, 2)) * len(MODULATION_GRID))
    return EffectScore("PressureModulation", ("a_pm", "f_m", "phi"), lm, 2, p, 0, False,
                       explained, {"f_m": f, "phi": phase})  # fmt: skip


def extend(result: FitResult, recording: Recording, effect, params=None, **fit_kwargs):
    """Add ``effect`` to the fitted model and refit, warm-started from the current fit.

    Arguments:
        result: the current fit.
        recording: its recording.
        effect: the term to add, at its off-value (e.g. ``GlottalGap()``).
        params: the effect's parameters to fit (default: all of them).
        fit_kwargs: passed to `vfjax.fit` (default: 40 PSO iterations, no progress bar).
    Returns the new `FitResult`; its model holds the effect.
    """
    from .fit import fit

    model = result.model.with_effect(effect)
    names = tuple(result.params) + tuple(params or type(effect).parameters)
    kwargs = {"iterations": 40, "progress": False, **fit_kwargs}
    return fit(model, recording, params=names, **kwargs)
