"""vfjax: the single-mass vocal-fold model as a differentiable, batched JAX simulator.

Importing vfjax enables 64-bit floats in JAX (``jax_enable_x64``): the model is stiff, its
event location needs double precision, and float32 silently loses the accuracy the fits and
derivatives rely on. This is the one process-wide setting vfjax changes; see the README.
"""

import jax

jax.config.update("jax_enable_x64", True)

from . import (  # noqa: E402
    asymmetry,
    compare,
    datasets,
    descriptors,
    diagnosis,
    phases,
    report,
    segmentation,
    units,
    video,
    workflow,
)
from ._diagnosis import (  # noqa: E402
    Calibration,
    Candidate,
    Criteria,
    Diagnosis,
    Investigation,
    RefitPlan,
    diagnose,
    investigate,
    score_tests,
)
from ._fit import (  # noqa: E402
    DEFAULT_PARAMS,
    FIRST_FIT_RESTARTS,
    FIT_STATUSES,
    PRESSURE_RANGE,
    FitResult,
    Polish,
    Swarm,
    default_warmup,
    first_fit_bounds,
    first_fit_parameters,
    fit,
    fit_many,
    fit_recording,
    search_range,
)
from ._sampling import Sampling, length_bucket  # noqa: E402
from ._validate import Constraint, as_parameter  # noqa: E402
from .cost import nmse  # noqa: E402
from .descriptors import estimate_closure_duration  # noqa: E402
from .integrator import (  # noqa: E402
    DEFAULT_SUBSTEPS,
    RESULTS,
    DenseOutput,
    Simulation,
    SimulationError,
    simulate,
)
from .model import VocalFoldModel  # noqa: E402
from .presets import PRESETS, initial_model, match_fundamental_frequency, paper_model, preset  # noqa: E402
from .recording import FRAME_RATE_RANGE_HZ, Recording, load_recording, load_segments  # noqa: E402
from .subject import Subject  # noqa: E402
from .terms import (  # noqa: E402
    AbstractForce,
    AbstractHoldVariability,
    AbstractObservation,
    AbstractPressure,
    AbstractStatefulForce,
    AbstractTerm,
    AmplitudeJitter,
    BernoulliForce,
    ClosureHold,
    ClosureJitter,
    Context,
    CubicStiffness,
    Elastic,
    FlowSeparation,
    GlottalGap,
    MucosalDelay,
    PowerLawTissue,
    PressureModulation,
    StiffnessJitter,
    TanhDamping,
    TimingJitter,
)

__version__ = "0.1.0"

__all__ = [
    "asymmetry",
    "compare",
    "descriptors",
    "datasets",
    "diagnosis",
    "report",
    "workflow",
    "segmentation",
    "video",
    "initial_model",
    "DEFAULT_SUBSTEPS",
    "FRAME_RATE_RANGE_HZ",
    "RESULTS",
    "SimulationError",
    "Constraint",
    "as_parameter",
    "load_segments",
    "PRESETS",
    "AbstractForce",
    "AbstractHoldVariability",
    "AbstractObservation",
    "AbstractPressure",
    "AbstractStatefulForce",
    "AbstractTerm",
    "AmplitudeJitter",
    "BernoulliForce",
    "ClosureHold",
    "ClosureJitter",
    "Context",
    "CubicStiffness",
    "GlottalGap",
    "MucosalDelay",
    "PowerLawTissue",
    "PressureModulation",
    "DenseOutput",
    "Elastic",
    "FitResult",
    "FlowSeparation",
    "Recording",
    "Simulation",
    "Subject",
    "TanhDamping",
    "VocalFoldModel",
    "Candidate",
    "Calibration",
    "Criteria",
    "RefitPlan",
    "Diagnosis",
    "Investigation",
    "diagnose",
    "investigate",
    "score_tests",
    "fit",
    "fit_many",
    "fit_recording",
    "first_fit_bounds",
    "first_fit_parameters",
    "DEFAULT_PARAMS",
    "FIRST_FIT_RESTARTS",
    "FIT_STATUSES",
    "PRESSURE_RANGE",
    "Polish",
    "Sampling",
    "StiffnessJitter",
    "TimingJitter",
    "Swarm",
    "estimate_closure_duration",
    "length_bucket",
    "match_fundamental_frequency",
    "search_range",
    "default_warmup",
    "load_recording",
    "nmse",
    "paper_model",
    "phases",
    "preset",
    "simulate",
    "units",
]
