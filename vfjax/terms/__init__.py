"""Model terms: each one a small `equinox.Module` adding one physical effect.

- `base`: the abstract kinds of term and the `Context` they read.
- `paper`: the five terms of the seed paper's model.
"""

from .base import (
    AbstractForce,
    AbstractObservation,
    AbstractPressure,
    AbstractTerm,
    Context,
)
from .paper import BernoulliForce, ClosureHold, Elastic, FlowSeparation, TanhDamping

__all__ = [
    "AbstractForce",
    "AbstractObservation",
    "AbstractPressure",
    "AbstractTerm",
    "BernoulliForce",
    "ClosureHold",
    "Context",
    "Elastic",
    "FlowSeparation",
    "TanhDamping",
]
