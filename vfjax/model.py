"""A vocal-fold model: the subject's constants, a tuple of terms, and the camera scale."""

import dataclasses
from collections.abc import Callable
from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, ArrayLike

from ._validate import as_parameter, check_constraints, constraints_hold, positive
from .subject import Subject
from .terms.base import (
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
from .terms.paper import BernoulliForce, ClosureHold, Elastic

# Parameters that live outside the terms: name -> (path from the model, unit).
_MODEL_PARAMETERS: dict[str, tuple[tuple[str, ...], str]] = {
    "S": (("S",), "px/mm²"),
    "P_s": (("subject", "subglottal_pressure"), "dyne/cm²"),
    "M": (("subject", "mass"), "g"),
    "l": (("subject", "length"), "cm"),
    "d": (("subject", "thickness"), "cm"),
    "A_g0": (("subject", "rest_area"), "cm²"),
}


#: The largest (fastest decay rate x RK4 step) a stateful term's states may see; RK4 is stable
#: up to 2.78.
_STIFF_LIMIT = 2.5


class VocalFoldModel(eqx.Module):
    """A single-mass vocal-fold model as a pytree (CGS units inside).

    Build the paper's model with `vfjax.paper_model` or `vfjax.preset`; add or remove terms
    with `with_term` / `without`; read and set parameters by name with `params` / `set`.

    Arguments:
        subject: the subject's constants (mass, length, thickness, rest area, air, P_s).
        terms: the model terms (forces, pressure and observation terms, closure hold).
        S: scaling factor from model area to image area (pixels per mm²).
    """

    subject: Subject
    terms: tuple[AbstractTerm, ...]
    S: ArrayLike = eqx.field(default=1.0, converter=as_parameter)
    constraints: ClassVar = (positive("S", "S (scaling factor)", "px/mm²"),)

    def __check_init__(self):
        if not isinstance(self.subject, Subject):
            raise TypeError(f"subject must be a vfjax.Subject, got {self.subject!r}")
        if not isinstance(self.terms, tuple):
            raise TypeError(f"terms must be a tuple of vfjax terms, got {self.terms!r}")
        for term in self.terms:
            if not isinstance(term, AbstractTerm):
                raise TypeError(f"terms must be vfjax terms, got {term!r}")
        check_constraints(self)
        self._check_subcritical()
        kinds = [type(t) for t in self.terms]
        if len(set(kinds)) != len(kinds):
            raise ValueError("a model holds at most one term of each class")
        if sum(isinstance(t, AbstractFoldPair) for t in self.terms) > 1:
            raise ValueError("a model holds at most one fold pair (one left-right asymmetry)")
        names: dict[str, str] = {}
        for term in self.terms:
            for name in term.parameters:
                if name in names or name in _MODEL_PARAMETERS:
                    raise ValueError(f"parameter name {name!r} appears twice in the model")
                names[name] = type(term).__name__

    # ------------------------------------------------------------ validity
    def check(self) -> "VocalFoldModel":
        """Raise ValueError, with the presets' messages, if a concrete parameter is outside
        its admissible range (values being traced are skipped); returns the model.

        Building a model checks it; so does `set`. A model changed otherwise (``eqx.tree_at``,
        ``jax.tree.map``) is not checked until this is called, or until `vfjax.simulate`
        reports it (``Simulation.result``)."""
        check_constraints(self.subject)
        for term in self.terms:
            check_constraints(term)
        check_constraints(self)
        self._check_subcritical()
        return self

    def is_valid(self):
        """Whether every parameter is admissible and the sub-critical displacement x_c
        exists (a traced boolean: usable inside jit, vmap and grad)."""
        ok = self.subject.is_valid() & constraints_hold(self)
        for term in self.terms:
            ok = ok & term.is_valid()
        return ok & jnp.isfinite(self.subcritical_displacement())

    def _check_subcritical(self):
        if any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(self)):
            return  # traced: `is_valid` reports it inside the computation
        xc = self.subcritical_displacement()
        if not bool(jnp.all(jnp.isfinite(xc))):
            raise ValueError(
                "the model has no sub-critical displacement x_c: with P_s = "
                f"{self.subject.subglottal_pressure} dyne/cm² and F_sa = "
                f"{self._aero().separation_force} dyne the aerodynamic force never falls to "
                "F_sa (check P_s and F_sa)"
            )

    # ----------------------------------------------------------------- terms
    def term(self, cls: type) -> AbstractTerm | None:
        """The model's term of class ``cls`` (or a subclass), or None."""
        for t in self.terms:
            if isinstance(t, cls):
                return t
        return None

    def has(self, cls: type) -> bool:
        """Whether the model has a term of class ``cls``."""
        return self.term(cls) is not None

    def with_term(self, term: AbstractTerm) -> "VocalFoldModel":
        """A copy with ``term`` added, replacing any term of the same class."""
        kept = tuple(t for t in self.terms if type(t) is not type(term))
        return VocalFoldModel(self.subject, kept + (term,), self.S)

    def with_effect(self, effect: AbstractTerm) -> "VocalFoldModel":
        """A copy with the effect added (or replaced); `with_term` by its diagnosis name."""
        return self.with_term(effect)

    def without(self, *classes: type) -> "VocalFoldModel":
        """A copy without the terms of the given classes (switches those effects off)."""
        missing = [c.__name__ for c in classes if not self.has(c)]
        if missing:
            raise ValueError(f"the model has no term {', '.join(missing)}")
        kept = tuple(t for t in self.terms if not isinstance(t, classes))
        return VocalFoldModel(self.subject, kept, self.S)

    # ------------------------------------------------------------ parameters
    def parameter_units(self) -> dict[str, str]:
        """Every parameter name of this model with its unit."""
        units = {name: unit for name, (_, unit) in _MODEL_PARAMETERS.items()}
        for term in self.terms:
            units.update({name: unit for name, (_, unit) in term.parameters.items()})
        return units

    def params(self) -> dict[str, Array]:
        """Every parameter of this model by name (values in the units of `parameter_units`)."""
        return {name: self._where(name)(self) for name in self.parameter_units()}

    def set(self, **values) -> "VocalFoldModel":
        """A copy with the named parameters replaced; traceable (usable inside jit/grad).

        Concrete values are checked (`check`): ``set(K=-1)`` raises ValueError."""
        model = self
        for name, value in values.items():
            model = eqx.tree_at(self._where(name), model, jnp.asarray(value, dtype=float))
        return model.check()

    def _where(self, name: str) -> Callable:
        if name in _MODEL_PARAMETERS:
            path = _MODEL_PARAMETERS[name][0]

            def get(m, path=path):
                for p in path:
                    m = getattr(m, p)
                return m

            return get
        for i, term in enumerate(self.terms):
            if name in term.parameters:
                field = term.parameters[name][0]
                return lambda m, i=i, field=field: getattr(m.terms[i], field)
        raise KeyError(f"no parameter {name!r}; this model has {sorted(self.parameter_units())}")

    # ---------------------------------------------------------------- physics
    @property
    def contact_displacement(self) -> Array:
        """x_0 (cm)."""
        return self.subject.contact_displacement

    def _aero(self) -> BernoulliForce:
        aero = self.term(BernoulliForce)
        return aero if aero is not None else BernoulliForce()

    def subcritical_displacement(self) -> Array:
        """x_c (cm) at the steady subglottal pressure: where F_a equals F_s.a."""
        s = self.subject
        area = self._aero().subcritical_area(
            s.subglottal_pressure, s.air_density, s.air_viscosity, s.thickness, s.length
        )
        return (area - s.rest_area) / (2.0 * s.length)

    @property
    def closure_duration(self):
        """t_c (s) of the closure hold, or None when the model has no hold."""
        hold = self.term(ClosureHold)
        return None if hold is None else hold.t_c

    def hold_duration(self, t: ArrayLike) -> Array:
        """Length (s) of a closure hold that starts at time ``t`` (s): t_c, times the factors
        of any `AbstractHoldVariability` term (cycle-to-cycle variability)."""
        duration = self.closure_duration
        for term in self.terms:
            if isinstance(term, AbstractHoldVariability):
                duration = duration * term.factor(t)
        return duration

    def pressure(self, t: ArrayLike) -> Array:
        """Subglottal pressure (dyne/cm²) at time ``t`` (s), after the pressure terms."""
        p = jnp.asarray(self.subject.subglottal_pressure, dtype=float)
        for term in self.terms:
            if isinstance(term, AbstractPressure):
                p = term.pressure(t, p)
        return p

    def context(self, t, x, v, flow, inner, closing, xc, pressure=None) -> Context:
        """The `Context` of the force terms at one instant and mode (``pressure``: the
        subglottal pressure at ``t`` if already computed)."""
        s = self.subject
        aero = self.term(BernoulliForce)
        pressure = self.pressure(t) if pressure is None else pressure
        if aero is None:
            f_a = jnp.zeros_like(x)
        else:
            f_open = aero.open_force(
                s.area(x), pressure, s.air_density, s.air_viscosity, s.thickness, s.length
            )
            f_a = jnp.where(flow, f_open, 0.0)
        elastic = self.term(Elastic)
        return Context(
            t=t,
            x=x,
            v=v,
            flow=flow,
            inner=inner,
            closing=closing,
            x0=s.contact_displacement,
            xc=xc,
            pressure=pressure,
            aero_force=f_a,
            stiffness=0.0 if elastic is None else elastic.K,
            mass=s.mass,
            length=s.length,
            thickness=s.thickness,
            area=s.area(x),
            area_rate=2.0 * s.length * v,
            air_density=s.air_density,
            air_viscosity=s.air_viscosity,
            aerodynamics=aero,
        )

    def acceleration(self, t, x, v, flow, inner, closing, xc, pressure=None, state=()) -> Array:
        """dv/dt (cm/s²) = sum of the force terms / M, in the given (frozen) mode
        (``pressure``: the subglottal pressure at ``t`` if already computed; ``state``: the
        internal states, as `initial_state` orders them)."""
        return self.rates(t, x, v, state, flow, inner, closing, xc, pressure)[0]

    def rates(
        self,
        t: ArrayLike,
        x: ArrayLike,
        v: ArrayLike,
        state: tuple,
        flow: ArrayLike,
        inner: ArrayLike,
        closing: ArrayLike,
        xc: ArrayLike,
        pressure: ArrayLike | None = None,
    ) -> tuple[Array, tuple]:
        """(dv/dt in cm/s², d state/dt) at one instant in the given (frozen) mode: the sum of
        the force terms over M, and each stateful term's `state_rate`.

        Arguments:
            t: time (s).
            x: displacement (cm).
            v: velocity (cm/s).
            state: the internal states of the stateful terms (`initial_state`'s layout).
            flow: frozen mode flag: air flows through the glottis (x > x_0; `vfjax.Context`).
            inner: frozen mode flag: the fold is inside the sub-critical displacement
                (x <= x_c).
            closing: frozen mode flag: the fold moves toward the midline (v < 0).
            xc: sub-critical displacement x_c (cm).
            pressure: the subglottal pressure at ``t`` (dyne/cm²) if already computed.
        """
        ctx = self.context(t, x, v, flow, inner, closing, xc, pressure)
        total, rates = self._forces(ctx, state)
        pair = self.term(AbstractFoldPair)
        if pair is None:
            return total / self.subject.mass, tuple(rates)

        def force(x_fold, v_fold):
            return self._forces(dataclasses.replace(ctx, x=x_fold, v=v_fold), state)[0]

        slot = rates.index(None)
        acceleration, rates[slot] = pair.fold_rates(ctx, state[slot], force)
        return acceleration, tuple(rates)

    def _forces(self, ctx: Context, state: tuple) -> tuple[Array, list]:
        """The force terms' sum (dyne) at ``ctx``, in the order of ``terms``, and each
        stateful force's state rate (None in a fold pair's place)."""
        total = jnp.zeros_like(jnp.asarray(ctx.x, dtype=float))
        states = iter(state)
        rates = []
        for term in self.terms:
            if isinstance(term, AbstractForce):
                total = total + term.force(ctx)
            elif isinstance(term, AbstractStatefulForce):
                own = next(states)
                total = total + term.force(ctx, own)
                rates.append(term.state_rate(ctx, own))
            elif isinstance(term, AbstractStatefulTerm):
                next(states)
                rates.append(None)
        return total, rates

    def initial_state(self) -> tuple:
        """The internal states at time 0: one pytree per `AbstractStatefulTerm` (stateful
        forces, a fold pair), in the order of ``terms``; an empty tuple for a model without
        any."""
        return tuple(t.initial_state() for t in self.terms if isinstance(t, AbstractStatefulTerm))

    def check_step(self, step: float) -> None:
        """Raise ValueError if an RK4 step of ``step`` seconds would integrate a stateful
        term's stiff states unstably (``max_rate * step`` beyond 2.5)."""
        for term in self.terms:
            rate = term.max_rate if isinstance(term, AbstractStatefulTerm) else 0.0
            if rate * step > _STIFF_LIMIT:
                raise ValueError(
                    f"{type(term).__name__} has states relaxing at up to {rate:.3g} 1/s: an RK4 "
                    f"step of {step:.3g} s integrates them unstably (it must stay below "
                    f"{_STIFF_LIMIT / rate:.3g} s); raise substeps (RK4 steps per frame)"
                )

    def held_state(self, state: tuple, duration: ArrayLike) -> tuple:
        """The internal states after a closure hold of ``duration`` (s)."""
        stateful = [t for t in self.terms if isinstance(t, AbstractStatefulTerm)]
        return tuple(t.held_state(z, duration) for t, z in zip(stateful, state, strict=True))

    def observe(self, t: Array, x: Array, displacement_at: Callable[[Array], Array]) -> Array:
        """Observed area in pixels at frame times ``t`` (s) with displacement ``x`` (cm)."""
        area = self.subject.area(x)
        for term in self.terms:
            if isinstance(term, AbstractObservation):
                area = term.observe(t, area, displacement_at, self.subject.length)
        return area * 100.0 * self.S

    @property
    def varies_pressure(self) -> bool:
        """Whether a pressure term makes the subglottal pressure depend on time."""
        return any(isinstance(t, AbstractPressure) for t in self.terms)

    @property
    def needs_history(self) -> bool:
        """Whether an observation term reads the displacement at other times."""
        return any(isinstance(t, AbstractObservation) and t.needs_history for t in self.terms)
