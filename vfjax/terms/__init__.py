"""Model terms: each one a small `equinox.Module` adding one physical effect.

- `base`: the abstract kinds of term and the `Context` they read.
- `paper`: the five terms of the seed paper's model.
- `effects`: candidate effects the paper's model lacks (MODEL_SPEC.md's catalogue).
- `variability`: cycle-to-cycle variability (closure, stiffness and amplitude jitter).
- `tissue`: power-law (fractional) viscoelastic tissue, a term with internal states.
- `folds`: left-right asymmetry, a left and a right fold in place of one.
- `tract`: source-tract interaction, the vocal tract's inertance loading the glottal flow.
"""

from .base import (
    AbstractFoldPair,
    AbstractForce,
    AbstractHoldVariability,
    AbstractObservation,
    AbstractPressure,
    AbstractStatefulForce,
    AbstractStatefulTerm,
    AbstractTerm,
    Context,
)
from .effects import CATALOGUE, CubicStiffness, GlottalGap, MucosalDelay, PressureModulation
from .folds import LeftRightAsymmetry
from .paper import BernoulliForce, ClosureHold, Elastic, FlowSeparation, TanhDamping
from .tissue import PowerLawTissue, grunwald_letnikov
from .tract import SourceTractInertance
from .variability import AmplitudeJitter, ClosureJitter, StiffnessJitter, TimingJitter

__all__ = [
    "AbstractFoldPair",
    "AbstractForce",
    "AbstractHoldVariability",
    "AbstractObservation",
    "AbstractPressure",
    "AbstractStatefulForce",
    "AbstractStatefulTerm",
    "AbstractTerm",
    "AmplitudeJitter",
    "BernoulliForce",
    "CATALOGUE",
    "CubicStiffness",
    "GlottalGap",
    "LeftRightAsymmetry",
    "MucosalDelay",
    "PowerLawTissue",
    "PressureModulation",
    "ClosureHold",
    "ClosureJitter",
    "Context",
    "Elastic",
    "FlowSeparation",
    "SourceTractInertance",
    "StiffnessJitter",
    "TimingJitter",
    "TanhDamping",
    "grunwald_letnikov",
]
