"""Input checks that run on concrete values, outside jit, and stay silent under tracing."""

import jax
import numpy as np


def _concrete(value):
    """The value as a NumPy array, or None when it is a tracer (inside jit/vmap/grad)."""
    if isinstance(value, jax.core.Tracer):
        return None
    try:
        return np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise TypeError(f"expected a number, got {value!r}") from err


def check_finite(name: str, value, unit: str = "") -> None:
    """Raise ValueError naming ``name`` if ``value`` has a NaN or infinity."""
    arr = _concrete(value)
    if arr is not None and not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite, got {_show(arr)}{_u(unit)}")


def check_positive(name: str, value, unit: str = "") -> None:
    """Raise ValueError naming ``name`` unless every element of ``value`` is finite and > 0."""
    check_finite(name, value, unit)
    arr = _concrete(value)
    if arr is not None and not np.all(arr > 0):
        raise ValueError(f"{name} must be > 0, got {_show(arr)}{_u(unit)}")


def check_nonnegative(name: str, value, unit: str = "") -> None:
    """Raise ValueError naming ``name`` unless every element of ``value`` is finite and >= 0."""
    check_finite(name, value, unit)
    arr = _concrete(value)
    if arr is not None and not np.all(arr >= 0):
        raise ValueError(f"{name} must be >= 0, got {_show(arr)}{_u(unit)}")


def check_in_range(name: str, value, low: float, high: float, unit: str = "") -> None:
    """Raise ValueError naming ``name`` unless ``low <= value < high`` elementwise."""
    check_finite(name, value, unit)
    arr = _concrete(value)
    if arr is not None and not np.all((arr >= low) & (arr < high)):
        raise ValueError(f"{name} must lie in [{low}, {high}), got {_show(arr)}{_u(unit)}")


def _show(arr: np.ndarray) -> str:
    return repr(arr.item()) if arr.ndim == 0 else np.array2string(arr, threshold=6)


def _u(unit: str) -> str:
    return f" {unit}" if unit else ""


def as_float(value):
    """Field converter: parameters are float arrays (pytree leaves, never static values)."""
    import jax.numpy as jnp

    return jnp.asarray(value, dtype=float)
