"""The paper's subjects N1-N4 (Tables 2-4) with the subglottal pressure of `MODEL_SPEC.md`."""

import numpy as np

from ._integrate import fitted_simulation
from ._sampling import Sampling
from .descriptors import estimate_closure_duration, fundamental_frequency
from .model import VocalFoldModel
from .recording import Recording
from .subject import Subject
from .terms.paper import BernoulliForce, ClosureHold, Elastic, FlowSeparation, TanhDamping
from .units import DYNE_PER_CM_PER_N_PER_M

#: Table 3 by sex: (vocal-fold mass in g, vocal-fold length in cm).
FOLD_BY_SEX = {"male": (0.12, 1.6), "female": (0.075, 1.0)}

#: Tables 3-4 and the inferred subglottal pressure, in the paper's units.
PRESETS: dict[str, dict] = {
    "N1": dict(
        sex="male",
        S_px_per_mm2=43.7988,
        K_N_per_m=396.6550,
        C_f_g_per_s=7536.2,
        t_c_s=5.25e-3,
        P_s_dyne_per_cm2=11250.0,
    ),
    "N2": dict(
        sex="male",
        S_px_per_mm2=70.7391,
        K_N_per_m=113.9710,
        C_f_g_per_s=11250.0,
        t_c_s=4.0e-3,
        P_s_dyne_per_cm2=11250.0,
    ),
    "N3": dict(
        sex="female",
        S_px_per_mm2=24.9649,
        K_N_per_m=671.1919,
        C_f_g_per_s=489.5168,
        t_c_s=2.75e-3,
        P_s_dyne_per_cm2=3500.0,
    ),
    "N4": dict(
        sex="female",
        S_px_per_mm2=29.6812,
        K_N_per_m=216.0464,
        C_f_g_per_s=829.8627,
        t_c_s=1.5e-3,
        P_s_dyne_per_cm2=3500.0,
    ),
}

#: The sidecar key of a measured subglottal pressure (dyne/cm²): the model takes it, and a
#: first fit (`vfjax.fit_recording`) does not search it.
PRESSURE_KEY = "subglottal_pressure_dyne_per_cm2"

#: The paper's reported normalised errors (%) for N1-N4 (Table 4), for reference only.
PAPER_NORMALISED_ERROR_PERCENT = {"N1": 1.8685, "N2": 1.9959, "N3": 2.1039, "N4": 2.8136}


def paper_model(
    *,
    K_N_per_m: float,
    C_f_g_per_s: float,
    S_px_per_mm2: float,
    t_c_s: float,
    P_s_dyne_per_cm2: float,
    sex: str | None = None,
    mass_g: float | None = None,
    length_cm: float | None = None,
    flow_separation: bool = True,
    closure_hold: bool = True,
) -> VocalFoldModel:
    """The seed paper's model from parameters in the paper's units.

    Arguments:
        K_N_per_m: stiffness K (N/m; stored as dyne/cm).
        C_f_g_per_s: damping amplification factor C_f (g/s).
        S_px_per_mm2: scaling factor S (pixels per mm²).
        t_c_s: closure duration t_c (s).
        P_s_dyne_per_cm2: subglottal pressure P_s (dyne/cm²).
        sex: "male" or "female", choosing Table 3's mass and length; or give both
            ``mass_g`` (g) and ``length_cm`` (cm).
        flow_separation: include the flow-separation force.
        closure_hold: include the closure hold.
    """
    if sex is not None:
        if sex not in FOLD_BY_SEX:
            raise ValueError(f"sex must be 'male' or 'female', got {sex!r}")
        mass_default, length_default = FOLD_BY_SEX[sex]
        mass_g = mass_default if mass_g is None else mass_g
        length_cm = length_default if length_cm is None else length_cm
    if mass_g is None or length_cm is None:
        raise ValueError("give sex='male'/'female', or both mass_g and length_cm")
    subject = Subject(mass=mass_g, length=length_cm, subglottal_pressure=P_s_dyne_per_cm2)
    terms = [
        Elastic(K=K_N_per_m * DYNE_PER_CM_PER_N_PER_M),
        TanhDamping(C_f=C_f_g_per_s),
        BernoulliForce(),
    ]
    if flow_separation:
        terms.append(FlowSeparation())
    if closure_hold:
        terms.append(ClosureHold(t_c=t_c_s))
    return VocalFoldModel(subject=subject, terms=tuple(terms), S=S_px_per_mm2)


def preset(name: str, **overrides) -> VocalFoldModel:
    """The paper's subject ``name`` ("N1".."N4"); keyword overrides go to `paper_model`."""
    if name not in PRESETS:
        raise ValueError(f"unknown preset {name!r}; choose one of {sorted(PRESETS)}")
    return paper_model(**{**PRESETS[name], **overrides})


def initial_model(recording: Recording, template: str | None = None) -> VocalFoldModel:
    """A starting model for ``recording``: the paper's preset for its sex (N1 male, N3
    female, or ``template``), with the sidecar's fold mass, length and subglottal pressure
    if given, the closure duration t_c measured on the GAW (`estimate_closure_duration`), as
    the paper did, and K matched to the recording's f0 (`match_fundamental_frequency`)."""
    sex = recording.metadata.get("sex")
    model = preset(template or ("N3" if sex == "female" else "N1"))
    if "vocal_fold_length_cm" in recording.metadata:
        model = model.set(l=recording.metadata["vocal_fold_length_cm"])
    if "vocal_fold_mass_g" in recording.metadata:
        model = model.set(M=recording.metadata["vocal_fold_mass_g"])
    if PRESSURE_KEY in recording.metadata:
        model = model.set(P_s=recording.metadata[PRESSURE_KEY])
    t_c = estimate_closure_duration(recording)
    if t_c is not None and model.closure_duration is not None:
        model = model.set(t_c=t_c)
    return match_fundamental_frequency(model, recording)


#: The shortest simulated motion whose f0 `match_fundamental_frequency` measures (s).
F0_WINDOW_S = 0.05


def match_fundamental_frequency(model: VocalFoldModel, recording: Recording, steps: int = 4):
    """``model`` with K scaled so that its f0 matches the recording's (secant steps in log K
    against log f0). A start at the right f0 keeps the swarm away from the sub-harmonic
    minima (a model at half the f0 fitting every other pulse)."""
    target = fundamental_frequency(recording.area, recording.fps)
    if not np.isfinite(target):
        return model
    # at least F0_WINDOW_S of motion, in frame counts that do not follow the frame rate (a
    # new frame rate reuses the program): 512 frames, doubled while too short
    n = 512
    while n < F0_WINDOW_S * recording.fps:
        n *= 2
    sampling = Sampling(recording.fps, max(n, recording.n_frames), warmup=0.02)

    def f0_of(k):  # one compiled program per length bucket, whatever the frame rate
        sim = fitted_simulation(model.set(K=k), sampling)
        if not bool(sim.complete):
            return float("nan")
        return fundamental_frequency(np.asarray(sim.area), recording.fps)

    k0 = float(model.params()["K"])
    f_0 = f0_of(k0)
    if not np.isfinite(f_0):
        return model
    k1 = k0 * (target / f_0) ** 2
    for _ in range(steps):
        f_1 = f0_of(k1)
        if not np.isfinite(f_1) or abs(f_1 / target - 1) < 0.005:
            break
        slope = (np.log(f_1) - np.log(f_0)) / (np.log(k1) - np.log(k0)) if k1 != k0 else 0.5
        slope = slope if slope > 0.05 else 0.5
        k0, f_0 = k1, f_1
        k1 = k1 * np.exp(np.log(target / f_1) / slope)
    return model.set(K=k1) if np.isfinite(f0_of(k1)) else model
