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

2. **Refits** (`RefitPlan`): the model with the effect is refitted, warm-started from the
   current fit and from the score test's one-step estimate of the effect's parameters (a
   few starts, one swarm each), giving the error each effect would reach. Every refit of a
   diagnosis runs through one compiled program: the model extended by every candidate, each
   swarm holding the candidates not its own at their off-values (`refit_each`). The leading
   candidate and the control are then refitted once more with a larger search (more swarms
   and iterations, ``RefitPlan.confirm_iterations``), so that the error and parameters
   reported for the effect to add are a thorough search's, not a quick one's. A leader whose
   quick refit already removes ``Criteria.min_fall`` of the error gets a search sized to its
   dimension: twice the swarms and a quarter more iterations per parameter beyond its first
   (a modulation's depth, frequency and phase: 4x the swarms, 1.5x the iterations).

An effect is *needed* when the evidence is significant at ``Criteria.alpha`` (Bonferroni-corrected
over the candidates; the evidence is twice the smaller p-value of the score test and of an F
test of the refit's error fall, on the residual's effective number of independent frames),
and its refit removes at least ``Criteria.min_fall`` of the squared error, and at least
``Criteria.noise_multiple`` (3) noise floors' worth of it (the NMSE that white measurement
noise alone leaves, `vfjax.compare.noise_level`): a few extra parameters fitted to noise and
cycle-to-cycle jitter remove less. (The refit's F test alone is not enough: on data with
jitter and no effect, a slow pressure modulation absorbs part of the drifting timing and its
F test, even on the effective number of frames, comes out "significant".) Falls are measured
from a control refit of the model without any effect, done the same way, so that a
refit that merely finds a better optimum of the fitted model does not count.
Candidates are ranked by the error their refit reaches (by p-value without refits). When no
effect is needed, or the best one explains little of the misfit, `Diagnosis.verdict` says so
in words, with where the model fails (`vfjax.compare`).

- ``_options``: `Criteria` and `RefitPlan`;
- ``_candidates``: `Candidate`, the catalogue's candidates and the model extended by them;
- ``_score``: the score tests and the GAW's sensitivities;
- ``_refits``: the refits' starts, `refit_each`, the confirming refit;
- ``_verdict``: `Diagnosis`, the refit's F test and the verdict in words;
- ``_diagnose``: `diagnose` and `extend`;
- ``_investigate``: `investigate` (fit, diagnose, extend, repeat).
"""

from ._candidates import DEFAULT_CANDIDATES, Candidate, default_candidates
from ._diagnose import diagnose, extend
from ._investigate import Investigation, Round, extend_from, investigate
from ._options import Criteria, RefitPlan
from ._refits import refit_each, refit_with
from ._score import EffectScore, score_tests
from ._verdict import Diagnosis, EffectRefit, effective_frames

__all__ = [
    "DEFAULT_CANDIDATES",
    "Candidate",
    "Criteria",
    "Diagnosis",
    "EffectRefit",
    "EffectScore",
    "Investigation",
    "RefitPlan",
    "Round",
    "default_candidates",
    "diagnose",
    "effective_frames",
    "extend",
    "extend_from",
    "investigate",
    "refit_each",
    "refit_with",
    "score_tests",
]
