"""The integrator: RK4 with located events, sampled at the camera rate.

Why events are located. The model switches between regimes (air flows or not, inside x_c or
not, closing or opening, held closed or free). A fixed-step scan that switches with
`jnp.where` masks evaluated at the RK4 stages has a zero derivative through every switch, so the
sensitivity of the switching *times* to the parameters is lost (`MODEL_SPEC.md`, "the trap").

How. Each scan iteration advances from the current time towards the next point of a uniform
step grid with the regime flags frozen (the vector field is then smooth). If a flag's
switching function changes sign over the trial step, the crossing is located on the step's
cubic Hermite interpolant, the iteration stops there (the state moves onto the switching
surface), the flag flips, and the next iteration continues from the event. The event time
comes from a Newton step on live values, so it carries its derivative (implicit function
theorem), and so does everything after it. The closure hold freezes the state for t_c from a
located start, so one iteration takes it to its release, whose time is differentiable too.

The state is the displacement and velocity plus the internal states of any stateful term
(`vfjax.AbstractStatefulForce`: relaxation modes, ...), stepped by the same RK4 and read off
their own Hermite cubics at an event. The result is a list of nodes (time, displacement,
velocity, internal states) with smooth dynamics between consecutive nodes. Frames are read
off this dense output by cubic Hermite interpolation at the camera times, so they too are
differentiable in every parameter and in the sampling time.

The iterations run in a loop that stops once every member of a batch has reached the last
frame (a member that finishes early idles). Its length is bounded by the steps on the grid plus
a budget for events; a recording that is held closed for half of each cycle needs about half
of that. A while loop has no reverse mode, so derivatives (forward and reverse) are taken
through a `lax.scan` of the bound's length that computes the same values.

The package: `_events` (the stepping: flags, one iteration, the early-stopping loop and the
differentiated scan), `_output` (`DenseOutput`, `Simulation`, `RESULTS` and what is read
off a simulation), `_simulate` (`simulate`, its validation and program), `_frames` (a fit's
compiled sampling: `SampledGrid`, `simulate_frames` and its two stages, `fitted_simulation`).
"""

from ._frames import (
    SampledGrid,
    fitted_simulation,
    integrate_window,
    integrate_window_single,
    sample_window,
    sampled_grid,
    simulate_frames,
    window_size,
)
from ._output import (
    RESULTS,
    DenseOutput,
    Simulation,
    SimulationError,
    fold_displacements,
    glottal_flow,
    left_share,
    simulated_fold_areas,
)
from ._simulate import simulate

# what the rest of vfjax imports (the public names among them re-exported by `vfjax`)
__all__ = [
    "RESULTS",
    "DenseOutput",
    "SampledGrid",
    "Simulation",
    "SimulationError",
    "fitted_simulation",
    "fold_displacements",
    "glottal_flow",
    "integrate_window",
    "integrate_window_single",
    "left_share",
    "sample_window",
    "sampled_grid",
    "simulate",
    "simulate_frames",
    "simulated_fold_areas",
    "window_size",
]
