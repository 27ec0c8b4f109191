"""Candidate effects: a term at its off-value and how the score test and the refits treat it."""

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp

from ..terms.base import AbstractTerm
from ..terms.effects import CubicStiffness, GlottalGap, MucosalDelay, PressureModulation
from ..terms.paper import ClosureHold, FlowSeparation

#: The candidates tried by default, in this order (those already active in the model are
#: skipped; FlowSeparation and ClosureHold only when absent or switched off).
DEFAULT_CANDIDATES = (
    GlottalGap,
    CubicStiffness,
    PressureModulation,
    MucosalDelay,
    FlowSeparation,
    ClosureHold,
)


@dataclasses.dataclass(frozen=True)
class Candidate:
    """A candidate effect: a term at its off-value and how to test it.

    Build one with `Candidate.of(TermClass)`; the settings come from the term class's
    ``off_values``, ``one_sided``, ``score_grid``, ``score_directions`` and ``score_point``.

    Attributes:
        name: the effect's name (its class name).
        term: the term, with the tested parameters at their off-values.
        tested: names of the parameters tested at their off-values.
        one_sided: one-sided test (only for a single tested column).
        grid: settings of other parameters searched by the score test.
        directions: settings whose columns are tested jointly.
        point: where the derivatives are taken.
    """

    name: str
    term: AbstractTerm
    tested: tuple[str, ...]
    one_sided: bool
    grid: tuple[dict, ...]
    directions: tuple[dict, ...]
    point: dict

    @classmethod
    def of(cls, effect: type | AbstractTerm) -> "Candidate":
        """The candidate for a term class (built at its off-values) or a term instance (its
        tested parameters are set to their off-values; its other parameters are kept)."""
        kind = effect if isinstance(effect, type) else type(effect)
        if not (isinstance(kind, type) and issubclass(kind, AbstractTerm)):
            raise TypeError(f"a candidate effect must be a vfjax term, got {effect!r}")
        if not kind.off_values:
            raise ValueError(
                f"{kind.__name__} declares no off_values: the diagnosis needs the "
                "parameter values that switch it off"
            )
        term = kind(**kind.off_values) if isinstance(effect, type) else effect
        for name, value in kind.off_values.items():
            field = kind.parameters[name][0]
            term = eqx.tree_at(lambda t, f=field: getattr(t, f), term, jnp.asarray(float(value)))
        tested = tuple(kind.off_values)
        directions = tuple(kind.score_directions)
        return cls(
            name=kind.__name__,
            term=term,
            tested=tested,
            one_sided=bool(kind.one_sided) and len(tested) * len(directions) == 1,
            grid=tuple(kind.score_grid),
            directions=directions,
            point={n: float(kind.score_point.get(n, kind.off_values[n])) for n in tested},
        )

    @property
    def extra(self) -> tuple[str, ...]:
        """Parameters set by the grid or the directions (fitted in the refit too)."""
        names = []
        for d in self.grid + self.directions:
            names += [n for n in d if n not in self.tested and n not in names]
        return tuple(names)

    @property
    def dof(self) -> int:
        return len(self.tested) * len(self.directions)

    def turned(self, offsets) -> list[dict]:
        """The phases (the settings that every direction sets, such as a modulation's
        phi) of the first direction moved by each of ``offsets`` (rad), wrapped to
        [-pi, pi); one empty setting where the directions have no phase."""
        first = self.directions[0]
        phases = [k for k in first if all(k in d for d in self.directions)]
        if not phases:
            return [{}]
        return [{k: wrap_angle(first[k] + a) for k in phases} for a in offsets]


def wrap_angle(angle):
    """``angle`` (rad) wrapped to [-pi, pi)."""
    return (angle + math.pi) % (2.0 * math.pi) - math.pi


def default_candidates(model) -> list[Candidate]:
    """`DEFAULT_CANDIDATES` that are absent from ``model`` (or present at their off-value)."""
    return offered(model, DEFAULT_CANDIDATES)


def offered(model, candidates) -> list[Candidate]:
    """The ``candidates`` (term classes, terms or `Candidate`s) that ``model`` lacks, or holds
    at their off-values: there a class is offered as the model's own term."""
    out = []
    for c in candidates:
        term = model.term(_kind(c))
        if term is None:
            out.append(c if isinstance(c, Candidate) else Candidate.of(c))
        elif is_off(term):
            out.append(c if isinstance(c, Candidate) else Candidate.of(term))
    return out


def _kind(candidate) -> type:
    """The term class of a candidate given as a `Candidate`, a term class or a term."""
    if isinstance(candidate, Candidate):
        return type(candidate.term)
    return candidate if isinstance(candidate, type) else type(candidate)


def is_off(term) -> bool:
    kind = type(term)
    return all(float(getattr(term, kind.parameters[n][0])) == v for n, v in kind.off_values.items())


def as_candidates(model, candidates):
    if candidates is None:
        return default_candidates(model)
    out = [c if isinstance(c, Candidate) else Candidate.of(c) for c in candidates]
    present = [
        c.name for c in out if model.has(type(c.term)) and not is_off(model.term(type(c.term)))
    ]
    if present:
        raise ValueError(f"{present} already active in the fitted model: nothing to test")
    return out


def extended(model, cands):
    """``model`` with every candidate's term added (at its off-value), or None if several
    candidates' parameter names clash."""
    for c in cands:
        model = model.with_term(c.term)
    declared = [n for t in model.terms for n in t.parameters]
    return model if len(cands) < 2 or len(declared) == len(set(declared)) else None
