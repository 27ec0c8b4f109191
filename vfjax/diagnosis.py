"""The diagnosis's names beyond the top level: which physical effect is missing.

`vfjax.diagnose` and `vfjax.investigate` are the entry points; this namespace holds what a
user combines with them (the catalogue's candidates, the refits, the statistics). The
method is described in the implementation's package, ``vfjax._diagnosis``.
"""

from ._diagnosis import (
    DEFAULT_CANDIDATES,
    AsymmetryTest,
    Calibrated,
    Candidate,
    Criteria,
    CycleVariability,
    Diagnosis,
    EffectRefit,
    EffectScore,
    RefitPlan,
    Variability,
    asymmetry_test,
    bootstrap_interval,
    calibrate,
    cycle_deviation,
    default_candidates,
    diagnose,
    extend,
    per_fold_nmse,
    refit_each,
    refit_replicates,
    refit_with,
    score_tests,
)

__all__ = [
    "DEFAULT_CANDIDATES",
    "AsymmetryTest",
    "asymmetry_test",
    "per_fold_nmse",
    "Calibrated",
    "Candidate",
    "Criteria",
    "CycleVariability",
    "cycle_deviation",
    "Diagnosis",
    "EffectRefit",
    "EffectScore",
    "RefitPlan",
    "default_candidates",
    "diagnose",
    "extend",
    "refit_each",
    "refit_replicates",
    "refit_with",
    "score_tests",
    "Variability",
    "calibrate",
    "bootstrap_interval",
]
