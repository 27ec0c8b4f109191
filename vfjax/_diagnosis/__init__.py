"""Which physical effect is missing? Score tests and refits from a fit.

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

2. **Refits and their calibration.** The search (`RefitPlan`): the model with each effect is
   refitted, warm-started from the current fit and from the score test's one-step estimate
   (a few starts, one swarm each), the control (the model alone) the same way; every search
   refit of a diagnosis runs through one compiled program, the fitted model extended by
   every candidate, each swarm holding the candidates not its own at their off-values
   (`refit_each`). These refits are where an extension starts (`extend_from`). The control
   is searched once more with more swarms and iterations (``RefitPlan.confirm_iterations``)
   and a longer polish (``RefitPlan.confirm_polish``), and so is the effect to add (the most
   significant, once the test below finds one).

   The test (`Calibration`, a parametric bootstrap): from the best fit without any effect,
   null recordings are simulated, each the fitted model with the recording's white noise and
   its cycle-to-cycle variability drawn afresh (`TimingJitter` offsets that scatter and that
   wander, a random walk of the periods, and `AmplitudeJitter` factors, in the proportions
   that reproduce the recording's per-cycle misfits: `Variability`), clipped and rounded
   like the recording. On the recording and on every null recording alike, one
   compiled program refits the control (a few Levenberg-Marquardt steps from the fit) and
   each candidate from the control's optimum with its parameters at a fixed lattice of
   starts, and from its search's fit (a modulation, whose error has many basins, not from
   its search's fit but, with ``Calibration.pool``, from the best of a pool of starts about
   the recording's starting model, `refit_jobs`); a candidate's refit never ends above the
   control. Each fall is put on one scale by its F test's p-value (degrees of freedom
   differ between candidates), centred on its median over the recording and the null
   recordings and scaled by its spread there (never below the F distribution's); a
   candidate's family-wise p-value is the share of null recordings whose largest
   standardised statistic over all candidates reaches the candidate's own, (1 + count) /
   (1 + null recordings).
   Null recordings come in batches, and stop as soon as every verdict is decided.

An effect is *needed* when its calibrated p-value is at most ``Criteria.alpha`` and the
interval of its size (a parametric bootstrap: recordings simulated from the model with the
effect at its refined values, each refitted from them) excludes its off-value; significant
with an interval that includes it, the effect is "detectable but not identifiable".
Candidates are ranked by calibrated p-value, ties (several beyond every null recording)
by their standardised statistic (`Calibrated.ranking`); by score p-value without refits. When no
effect is needed, `Diagnosis.verdict` says so in words, with where the model fails
(`vfjax.compare`).

3. **Cycle-to-cycle variability** (`CycleVariability`, `Diagnosis.variability`), where no
   candidate is significant. The candidates' null recordings carry the recording's own
   variability; variability itself is tested against null recordings of the fitted model
   with white noise only (at the level the per-cycle fit below leaves). The statistic is the
   misfit that changes from cycle to cycle (`cycle_deviation`: the residual cut at the
   fitted GAW's cycles, less the misfit every cycle shares, which an effect may explain),
   its p-value a rank among the null recordings'. Its size: one timing offset (s) and one
   amplitude factor per cycle (`TimingJitter`, `AmplitudeJitter`, slots of one period),
   fitted to the recording together with the fitted parameters; the spread of the offsets
   about a line (a trend is a change of period) and of the factors about their mean, less
   what the same fit adds to the spreads of simulated recordings (white noise only, then the
   spreads found), with chi-square intervals on the cycles' count. The recording varies
   beyond its noise when the p-value is at most alpha and an interval excludes zero.

- ``_options``: `Criteria`, `RefitPlan` and `Calibration`;
- ``_nulls``: the null recordings of a fit and their variability (`Variability`);
- ``_statistic``: the refit statistic computed alike on the recording and its null
  recordings, and its family-wise p-values;
- ``_calibration``: `calibrate` (the statistic against null recordings, sequentially, and
  the needed effects' intervals);
- ``_cycles``: `CycleVariability`, cycle-to-cycle variability tested and sized;
- ``_candidates``: `Candidate`, the catalogue's candidates and the model extended by them;
- ``_score``: the score tests and the GAW's sensitivities;
- ``_refits``: the refits' starts, `refit_each`, the confirming refit, the bootstrap's
  replicates refitted (`refit_replicates`);
- ``_verdict``: `Diagnosis`, `EffectRefit` and the verdict in words;
- ``_diagnose``: `diagnose` and `extend`;
- ``_investigate``: `investigate` (fit, diagnose, extend, repeat);
- ``_folds``: `asymmetry_test`, left-right asymmetry tested on each fold's area.
"""

from ._calibration import Calibrated, bootstrap_interval, calibrate
from ._candidates import DEFAULT_CANDIDATES, Candidate, default_candidates
from ._cycles import CycleVariability, cycle_deviation
from ._diagnose import diagnose, extend
from ._folds import AsymmetryTest, asymmetry_test, per_fold_nmse
from ._investigate import EXPLAINED_SHARE, Investigation, Outcome, Round, extend_from, investigate
from ._nulls import Variability
from ._options import Calibration, Criteria, RefitPlan
from ._refits import refit_each, refit_replicates, refit_with
from ._score import EffectScore, score_tests
from ._verdict import Diagnosis, EffectRefit

__all__ = [
    "AsymmetryTest",
    "asymmetry_test",
    "per_fold_nmse",
    "DEFAULT_CANDIDATES",
    "Calibrated",
    "Calibration",
    "Candidate",
    "Criteria",
    "CycleVariability",
    "cycle_deviation",
    "Diagnosis",
    "EffectRefit",
    "EffectScore",
    "EXPLAINED_SHARE",
    "Investigation",
    "Outcome",
    "RefitPlan",
    "Round",
    "default_candidates",
    "diagnose",
    "extend",
    "extend_from",
    "investigate",
    "refit_each",
    "refit_replicates",
    "refit_with",
    "score_tests",
    "Variability",
    "bootstrap_interval",
    "calibrate",
]
