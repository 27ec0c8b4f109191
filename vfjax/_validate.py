"""Checks of parameter values: raised on concrete values (outside jit), and available as a
traced boolean (inside jit/vmap/grad) for `vfjax.simulate`'s ``invalid_parameters`` result.

A module lists its checks once, as ``constraints`` (a tuple of `Constraint`); the same tuple
serves both uses, so the messages of a preset, of ``model.set(...)`` and of a loaded file are
the same.
"""

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class Constraint(NamedTuple):
    """A field's admissible values: finite, and ``low < value`` (``low <= value`` when
    ``closed_low``) and ``value < high``.

    Attributes:
        field: the module's field name.
        label: how messages name it, e.g. "K (stiffness)".
        low, high: the bounds, in the field's unit.
        closed_low: whether ``low`` itself is admissible.
        unit: the unit, for messages.
    """

    field: str
    label: str
    low: float = -math.inf
    high: float = math.inf
    closed_low: bool = True
    unit: str = ""

    def describe(self) -> str:
        if self.high < math.inf:
            return f"lie in {'[' if self.closed_low else '('}{self.low:g}, {self.high:g})"
        if self.low == -math.inf:
            return "be finite"
        return f"be {'>=' if self.closed_low else '>'} {self.low:g}"

    def check(self, value) -> None:
        """Raise ValueError naming the field if a concrete ``value`` is inadmissible."""
        arr = _concrete(value)
        if arr is None:
            return
        if not np.all(np.isfinite(arr)):
            raise ValueError(f"{self.label} must be finite, got {_show(arr)}{_u(self.unit)}")
        if not np.all(self._holds(arr)):
            raise ValueError(
                f"{self.label} must {self.describe()}, got {_show(arr)}{_u(self.unit)}"
            )

    def holds(self, value):
        """Whether ``value`` is admissible, as a traced boolean scalar."""
        value = jnp.asarray(value)
        return jnp.all(jnp.isfinite(value) & self._holds(value))

    def _holds(self, value):
        above = value >= self.low if self.closed_low else value > self.low
        return above & (value < self.high)


def positive(field: str, label: str, unit: str = "") -> Constraint:
    """A field that must be finite and > 0."""
    return Constraint(field, label, 0.0, math.inf, False, unit)


def nonnegative(field: str, label: str, unit: str = "") -> Constraint:
    """A field that must be finite and >= 0."""
    return Constraint(field, label, 0.0, math.inf, True, unit)


def finite(field: str, label: str, unit: str = "") -> Constraint:
    """A field that must be finite."""
    return Constraint(field, label, unit=unit)


def in_range(field: str, label: str, low: float, high: float, unit: str = "") -> Constraint:
    """A field that must lie in ``[low, high)``."""
    return Constraint(field, label, low, high, True, unit)


def check_constraints(module) -> None:
    """Raise ValueError for the first concrete field of ``module`` that breaks its class's
    ``constraints``; tracers are skipped."""
    for c in type(module).constraints:
        c.check(getattr(module, c.field))


def constraints_hold(module):
    """Whether every field of ``module`` meets its class's ``constraints`` (traced bool)."""
    ok = jnp.asarray(True)
    for c in type(module).constraints:
        ok = ok & c.holds(getattr(module, c.field))
    return ok


def _concrete(value):
    """The value as a NumPy array, or None when it is a tracer (inside jit/vmap/grad)."""
    if isinstance(value, jax.core.Tracer):
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise TypeError(f"expected a number, got {value!r}") from err


def is_count(value) -> bool:
    """Whether ``value`` is a count of at least one: a Python int >= 1 (a bool, a float or a
    NumPy scalar is not)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def check_positive(name: str, value, unit: str = "") -> None:
    """Raise ValueError naming ``name`` unless every element of ``value`` is finite and > 0."""
    positive("value", name, unit).check(value)


def check_nonnegative(name: str, value, unit: str = "") -> None:
    """Raise ValueError naming ``name`` unless every element of ``value`` is finite and >= 0."""
    nonnegative("value", name, unit).check(value)


def _show(arr: np.ndarray) -> str:
    return repr(arr.item()) if arr.ndim == 0 else np.array2string(arr, threshold=6)


def _u(unit: str) -> str:
    return f" {unit}" if unit else ""


def check_schema(data, schema_file: str, where: str, what: str) -> None:
    """Raise ValueError if ``data`` breaks the JSON schema ``vfjax/schemas/<schema_file>``
    (``data_schema/`` in the repository), naming ``where``, ``what`` it should be, and the
    first few fields at fault with what is wrong with each."""
    import json
    import pathlib

    import jsonschema

    path = pathlib.Path(__file__).parent / "schemas" / schema_file
    schema = json.loads(path.read_text())
    errors = sorted(jsonschema.Draft202012Validator(schema).iter_errors(data), key=str)
    if errors:
        fields = []
        for err in errors[:5]:
            field = ".".join(map(str, err.absolute_path)) or "(top level)"
            fields.append(f"{field}: {err.message:.200}")
        raise ValueError(f"{where}: {what}: " + "; ".join(fields))


def as_parameter(value):
    """Field converter for a term's parameters: a floating-point array (a pytree leaf that
    `jax.grad` and `eqx.filter_grad` differentiate). ``jnp.asarray`` would keep an integer
    ``1`` an integer array, which filters treat as a constant: use this converter instead."""
    return jnp.asarray(value, dtype=float)
