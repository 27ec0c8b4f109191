"""The kinds of model term and the context they are evaluated in.

A term is an `equinox.Module` whose array fields are its parameters (pytree leaves). It is one
of these kinds, told apart by which abstract class it derives from:

- `AbstractForce`: adds a force (dyne) on one fold to the equation of motion.
- `AbstractStatefulForce`: a force with internal states of its own (relaxation modes, a
  flow), integrated with the folds' motion by the same event-located RK4.
- `AbstractFoldPair`: a left and a right fold in place of the one symmetric fold, their
  difference held as internal states (`AbstractStatefulTerm`, like the stateful forces').
- `AbstractPressure`: transforms the subglottal pressure as a function of time.
- `AbstractObservation`: transforms the glottal area that the camera sees.
- `AbstractHoldVariability`: scales the length of each closure hold (cycle-to-cycle
  variability).
- `ClosureHold` (in `paper.py`): the discrete closure hold, handled by the integrator.

Every term class lists the user-facing names of its parameters in ``parameters``, a mapping
``name -> (field, unit)``, so that a model can be read and updated by name (``model.params()``,
``model.set(K=...)``). Names are unique within a model.
"""

import abc
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike, Bool, PyTree

from .._validate import Constraint, check_constraints, constraints_hold


class AbstractTerm(eqx.Module):
    """Base of every model term. ``parameters`` maps public names to ``(field, unit)``.

    Parameter fields must hold floating-point arrays: declare them with
    ``eqx.field(converter=vfjax.as_parameter)``. An integer leaf (``jnp.asarray(1)``) is a
    constant to `eqx.filter_grad`, which would silently return no gradient for it, so a term
    built with one is refused.
    """

    parameters: ClassVar[dict[str, tuple[str, str]]] = {}
    #: The admissible values of the term's fields (`vfjax.Constraint`): checked when the term
    #: is built or changed with concrete values, and by `vfjax.simulate` (its
    #: ``invalid_parameters`` result) when traced.
    constraints: ClassVar[tuple[Constraint, ...]] = ()
    #: The parameter values that switch the term off while keeping it in the model
    #: (used by the diagnosis's score test); empty when removing the term is the only way.
    off_values: ClassVar[dict[str, float]] = {}
    #: Diagnosis settings (see `vfjax.diagnose`): whether the off-value is a boundary (a
    #: gap, a delay, a strength >= 0; the score test is then one-sided) ...
    one_sided: ClassVar[bool] = False
    #: ... settings of the parameters that do not exist at the off-value, searched by the
    #: score test (e.g. a modulation's frequency) ...
    score_grid: ClassVar[tuple[dict[str, float], ...]] = ({},)
    #: ... settings whose columns are tested together (e.g. a sine and a cosine phase) ...
    score_directions: ClassVar[tuple[dict[str, float], ...]] = ({},)
    #: ... and where the derivatives are taken, if not exactly at the off-values.
    score_point: ClassVar[dict[str, float]] = {}
    #: Search range ``(low, high, scale)`` of parameters fitted in linear coordinates (those
    #: starting at an off-value of 0), in the parameter's unit; see `vfjax.search_range`.
    ranges: ClassVar[dict[str, tuple[float, float, float]]] = {}
    #: The least simulated time before the first frame (s) that a fit of a model with this
    #: term needs (`vfjax.fit`'s default warm-up is the largest of its terms'): a term whose
    #: effect has a memory longer than the default 20 ms (a slow modulation) must start early
    #: enough for its history to be in the state at the first frame.
    min_warmup: ClassVar[float] = 0.0

    def __check_init__(self):
        for name, (field, unit) in self.parameters.items():
            value = getattr(self, field)
            dtype = jnp.result_type(value)
            if not jnp.issubdtype(dtype, jnp.inexact):
                raise TypeError(
                    f"{type(self).__name__}.{field} (parameter {name}, {unit}) is a {dtype} "
                    "array: gradients skip non-float leaves. Declare the field with "
                    "eqx.field(converter=vfjax.as_parameter)"
                )
        check_constraints(self)

    def is_valid(self):
        """Whether every field meets the term's ``constraints`` (a traced boolean)."""
        return constraints_hold(self)

    @classmethod
    def guess(cls, recording) -> dict[str, float]:
        """Starting values of the term's parameters read off a recording (for the
        diagnosis's refit), where the data show them directly; empty by default."""
        return {}


class Context(eqx.Module):
    """Everything a force term may read at one instant (CGS units).

    The discrete mode flags (``flow``, ``inner``, ``closing``) are frozen over each integration
    segment and switched only at located events; terms must use them, not recompute them from
    ``x`` and ``v``, so that the vector field stays smooth within a segment.

    Attributes:
        t: time (s).
        x: displacement of one fold from its rest position (cm), positive = abducted.
        v: velocity (cm/s).
        flow: air flows through the glottis (x > x_0).
        inner: the fold is inside the sub-critical displacement (x <= x_c).
        closing: the fold moves toward the midline (v < 0).
        x0: contact displacement x_0 (cm).
        xc: sub-critical displacement x_c (cm), where the aerodynamic force equals F_s.a.
        pressure: subglottal pressure at time t (dyne/cm²).
        aero_force: Bernoulli aerodynamic force F_a at this instant (dyne), 0 without flow.
        stiffness: linear stiffness K of the model's elastic term (dyne/cm), 0 if none.
        mass, length, thickness: the subject's M (g), l (cm) and d (cm).
        area: glottal area A = A_g0 + 2 l x (cm²) of the folds' mean displacement.
        area_rate: dA/dt = 2 l v (cm²/s) of the folds' mean velocity.
        air_density, air_viscosity: the subject's rho (g/cm³) and mu (poise).
        aerodynamics: the model's `BernoulliForce` term (its flow and force at any area and
            pressure drop), or None.
    """

    t: ArrayLike
    x: ArrayLike
    v: ArrayLike
    flow: Bool[Array, ""]
    inner: Bool[Array, ""]
    closing: Bool[Array, ""]
    x0: ArrayLike
    xc: ArrayLike
    pressure: ArrayLike
    aero_force: ArrayLike
    stiffness: ArrayLike
    mass: ArrayLike
    length: ArrayLike
    thickness: ArrayLike
    area: ArrayLike
    area_rate: ArrayLike
    air_density: ArrayLike
    air_viscosity: ArrayLike
    aerodynamics: "AbstractForce | None"


class AbstractForce(AbstractTerm):
    """A force on one fold (dyne), smooth in (t, x, v) for fixed mode flags."""

    def force(self, ctx: Context) -> Array:
        """The force (dyne) at the instant described by ``ctx``."""
        raise NotImplementedError


class AbstractStatefulTerm(AbstractTerm):
    """A term with internal states of its own, integrated with the folds' displacement and
    velocity by the same event-located RK4.

    The states (a pytree of float arrays) start at `initial_state`; where a regime switches
    they are read off the step's cubic Hermite interpolant, so their derivatives carry the
    event time's. During a closure hold the folds rest (x fixed, v = 0) and the states become
    `held_state` after the hold's duration. A model without such a term carries no internal
    state: its programs are those of a model whose state is the displacement and velocity
    alone.
    """

    #: The fastest decay rate of the states (1/s), if they are stiff: RK4 is stable for
    #: ``max_rate * h < 2.78``, so `vfjax.simulate` and the fits refuse a step h beyond it.
    max_rate: ClassVar[float] = 0.0

    @abc.abstractmethod
    def initial_state(self) -> PyTree[Array]:
        """The states at time 0, with the folds at rest (float arrays of fixed shapes)."""

    def held_state(self, state: PyTree[Array], duration: ArrayLike) -> PyTree[Array]:
        """The states after ``duration`` (s) of closure hold (x fixed, v = 0); by default
        unchanged. A term whose states evolve while the folds rest overrides it with the
        exact solution of its dynamics at v = 0."""
        return state


class AbstractStatefulForce(AbstractStatefulTerm):
    """A force on one fold (dyne) that depends on internal states of the term's own (e.g.
    the relaxation modes of a viscoelastic tissue), which obey
    ``d state / dt = state_rate(ctx, state)``."""

    @abc.abstractmethod
    def state_rate(self, ctx: Context, state: PyTree[Array]) -> PyTree[Array]:
        """d state / dt at the instant ``ctx`` (the states' units per second)."""

    @abc.abstractmethod
    def force(self, ctx: Context, state: PyTree[Array]) -> Array:
        """The force (dyne) at the instant ``ctx`` with internal ``state``."""


class AbstractFoldPair(AbstractStatefulTerm):
    """A left and a right fold in place of the paper's one symmetric fold.

    The integrator's displacement x becomes the folds' mean, ``(x_left + x_right) / 2``: the
    glottal area ``A_g0 + l (x_left + x_right) = A_g0 + 2 l x``, and with it the flow, the
    contact and every located event, depend on it alone. The term's internal states describe
    how the folds differ; it turns the force on one fold (every force term evaluated at that
    fold's displacement and velocity, with the glottis's shared mode flags and aerodynamic
    force) into the mean's acceleration and its states' rates.
    """

    # The states are (value, rate) pairs along their last axis, (d_1, dd_1/dt, d_2, ...):
    # between the integrator's nodes they are read on cubic Hermite interpolants
    # (`vfjax.fold_displacements`), as the displacement is.

    @abc.abstractmethod
    def fold_rates(
        self, ctx: Context, state: PyTree[Array], force: Callable[[Array, Array], Array]
    ) -> tuple[Array, PyTree[Array]]:
        """(d²x/dt² of the folds' mean displacement in cm/s², d state / dt).

        Arguments:
            ctx: the instant, at the folds' mean displacement and velocity.
            state: the term's internal states.
            force: ``force(x, v)``, the force (dyne) of the model's force terms on a fold at
                displacement ``x`` (cm) moving at ``v`` (cm/s) at this instant.
        """

    @abc.abstractmethod
    def fold_displacements(self, x: ArrayLike, state: PyTree[Array]) -> tuple[Array, Array]:
        """(x_left, x_right) in cm, from the mean displacement ``x`` (cm) and the states
        (their leaves with the same leading axes as ``x``)."""


class AbstractPressure(AbstractTerm):
    """A transformation of the subglottal pressure over time."""

    def pressure(self, t: ArrayLike, mean_pressure: ArrayLike) -> Array:
        """Pressure (dyne/cm²) at time ``t`` (s, from the start of sampling, `vfjax.simulate`'s
        ``t_start``; negative during the warm-up) given the steady pressure ``mean_pressure``."""
        raise NotImplementedError


class AbstractObservation(AbstractTerm):
    """A transformation of the glottal area on its way to the camera."""

    #: True when the term needs the displacement at times other than the frame times.
    needs_history: ClassVar[bool] = False

    def observe(
        self,
        t: Array,
        area: Array,
        displacement_at: Callable[[Array], Array],
        length: ArrayLike,
    ) -> Array:
        """Observed area (cm²) at frame times ``t`` (s).

        Arguments:
            t: frame times (s).
            area: the area so far (cm²) at those times.
            displacement_at: maps an array of times (s) to the fold displacement (cm), from
                the integrator's dense output.
            length: vocal-fold length l (cm).
        """
        raise NotImplementedError


class AbstractHoldVariability(AbstractTerm):
    """A factor on the length of each closure hold, by the time the hold starts."""

    def factor(self, t: ArrayLike) -> Array:
        """Factor (dimensionless) on t_c for a hold starting at time ``t`` (s)."""
        raise NotImplementedError
