"""Models and fit results to and from plain JSON-ready dicts, without loss.

A saved file is data, never code. Reading one validates it against its schema
(``data_schema/fit_result.schema.json``) before anything is built, and resolves each term's
class name only among vfjax's own terms (`BUILTIN_TERMS`) and the classes the caller passes
on purpose (``terms=``): nothing is imported, and no other class is called.
"""

import dataclasses
import json
import pathlib

import equinox as eqx
import numpy as np

from ._validate import check_schema
from .model import VocalFoldModel
from .subject import Subject
from .terms import (
    CATALOGUE,
    ClosureJitter,
    LeftRightAsymmetry,
    PowerLawTissue,
    SourceTractInertance,
)
from .terms.base import AbstractTerm
from .terms.paper import BernoulliForce, ClosureHold, Elastic, FlowSeparation, TanhDamping

#: The term classes a saved model may name without being passed to the reader.
BUILTIN_TERMS: tuple[type[AbstractTerm], ...] = (
    *(Elastic, TanhDamping, BernoulliForce, FlowSeparation, ClosureHold),
    *CATALOGUE,
    PowerLawTissue,
    SourceTractInertance,
    LeftRightAsymmetry,
    ClosureJitter,
)
#: Saved fit results larger than this (bytes) are refused unread.
MAX_FILE_BYTES = 64 * 2**20
SCHEMA_ID = "vfjax.fit_result/3"


def _qualname(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"


def _value(v):
    arr = np.asarray(v)
    return arr.item() if arr.ndim == 0 else arr.tolist()


def _module_to_dict(m: eqx.Module) -> dict:
    fields = {f.name: _value(getattr(m, f.name)) for f in dataclasses.fields(m)}
    return {"class": _qualname(type(m)), "fields": fields}


def _term_class(name: str, allowed, where: str) -> type[AbstractTerm]:
    """The allowed class a saved name refers to: by its full ``module:qualname``, else by
    its class name alone (vfjax's own terms keep their names when modules move)."""
    exact = [c for c in allowed if _qualname(c) == name]
    if exact:
        return exact[0]
    short = name.rpartition(":")[2]
    by_name = [c for c in allowed if c.__qualname__ == short]
    if len(by_name) == 1:
        return by_name[0]
    known = ", ".join(sorted(c.__name__ for c in allowed))
    raise ValueError(
        f"{where}: refusing term class {name!r}: a saved model may name only vfjax's own "
        f"terms ({known}) or classes passed on purpose, e.g. "
        f"FitResult.from_json(path, terms=[{short or 'MyTerm'}])"
    )


def _numeric(value) -> bool:
    if isinstance(value, bool):
        return False
    if isinstance(value, (int, float)):
        return True
    return isinstance(value, list) and all(_numeric(v) for v in value)


def _build(cls, fields: dict, where: str):
    if not isinstance(fields, dict):
        raise ValueError(f"{where}: the fields of {cls.__name__} must be an object")
    names = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(fields) - names)
    if unknown:
        raise ValueError(
            f"{where}: {cls.__name__} has no field(s) {unknown}; its fields are {sorted(names)}"
        )
    bad = [k for k, v in fields.items() if not _numeric(v)]
    if bad:
        raise ValueError(
            f"{where}: {cls.__name__}.{bad[0]} must be a number or a list of "
            f"numbers, got {fields[bad[0]]!r:.60}"
        )
    try:
        return cls(**fields)
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: cannot build {cls.__name__}: {err}") from None


def model_to_dict(model: VocalFoldModel) -> dict:
    """A model as a dict: the subject's fields, each term's class and fields, and S."""
    return {
        "subject": _module_to_dict(model.subject)["fields"],
        "terms": [_module_to_dict(t) for t in model.terms],
        "S": _value(model.S),
    }


def model_from_dict(d: dict, terms=(), where: str = "model") -> VocalFoldModel:
    """Inverse of `model_to_dict`.

    Arguments:
        d: the dict.
        terms: term classes besides `BUILTIN_TERMS` that ``d`` may name (your own effects).
        where: what to call the source in error messages (a file name).
    """
    allowed = tuple(BUILTIN_TERMS) + tuple(terms)
    for cls in terms:
        if not (isinstance(cls, type) and issubclass(cls, AbstractTerm)):
            raise TypeError(f"terms must be vfjax term classes, got {cls!r}")
    if not isinstance(d, dict) or not {"subject", "terms", "S"} <= set(d):
        raise ValueError(f"{where}: a model needs 'subject', 'terms' and 'S'")
    if not isinstance(d["terms"], list):
        raise ValueError(f"{where}: 'terms' must be a list")
    built = []
    for t in d["terms"]:
        if not isinstance(t, dict) or not isinstance(t.get("class"), str):
            raise ValueError(f"{where}: each term needs a 'class' name and 'fields'")
        cls = _term_class(t["class"], allowed, where)
        built.append(_build(cls, t.get("fields", {}), where))
    subject = _build(Subject, d["subject"], where)
    if not _numeric(d["S"]):
        raise ValueError(f"{where}: S must be a number")
    try:
        return VocalFoldModel(subject=subject, terms=tuple(built), S=d["S"])
    except (TypeError, ValueError) as err:
        raise ValueError(f"{where}: invalid model: {err}") from None


def fit_result_to_dict(result) -> dict:
    """A `FitResult` as a JSON-ready dict (schema: data_schema/fit_result.schema.json)."""
    out = {f.name: getattr(result, f.name) for f in dataclasses.fields(result)}
    out["model"] = None if result.model is None else model_to_dict(result.model)
    out["sampling"] = result.sampling.to_dict()
    out["swarm"] = result.swarm.to_dict()
    out["schema"] = SCHEMA_ID
    return out


def validate_fit_result(d, where: str = "fit result") -> None:
    """Check a saved fit result against ``data_schema/fit_result.schema.json``; the error
    names the field and what is wrong with it."""
    check_schema(d, "fit_result.schema.json", where, "not a vfjax fit result")


def _from_settings(d: dict, where: str) -> dict:
    """The /3 fields of a /1 or /2 file's ``settings``."""
    settings = d.pop("settings")
    if "fps" not in settings or "n_frames" not in settings:
        raise ValueError(
            f"{where}: this {d['schema']} file does not record the frame rate and frame "
            "count of its fit; fit the recording again"
        )
    pso = settings.get("pso", {})
    d["sampling"] = {k: settings[k] for k in ("fps", "n_frames", "substeps", "warmup")}
    d["sampling"]["max_time_shift"] = settings["max_time_shift"]
    d["bounds"] = settings.get("bounds", {})
    d["swarm"] = {
        "size": settings.get("swarm_size", 48),
        "iterations": settings.get("iterations", 60),
        **{k: v for k, v in pso.items() if k != "boundary" or isinstance(v, str)},
    }
    return d


def fit_result_from_dict(d: dict, terms=(), where: str = "fit result") -> dict:
    """Inverse of `fit_result_to_dict`, as the fields of a `FitResult` (validated against the
    schema first; ``terms`` as for `model_from_dict`), with ``sampling`` and ``swarm`` as
    dicts of their fields."""
    validate_fit_result(d, where)
    d = dict(d)
    if d["schema"] != SCHEMA_ID:
        d = _from_settings(d, where)
    schema = d.pop("schema")
    d.setdefault("status", "unknown" if schema == "vfjax.fit_result/1" else "successful")
    d["model"] = None if d.get("model") is None else model_from_dict(d["model"], terms, where)
    return d


def read_fit_result(path, terms=()) -> dict:
    """The fields of a `FitResult` from a JSON file written by `FitResult.to_json`; see
    `fit_result_from_dict`."""
    path = pathlib.Path(path)
    if not path.exists():
        raise FileNotFoundError(f"no fit result at {path}")
    if path.stat().st_size > MAX_FILE_BYTES:
        raise ValueError(
            f"{path}: {path.stat().st_size} bytes, larger than a fit result can be "
            f"({MAX_FILE_BYTES} bytes)"
        )
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise ValueError(f"{path}: not a JSON text file") from None
    except json.JSONDecodeError as err:
        raise ValueError(f"{path}: invalid JSON: {err}") from None
    return fit_result_from_dict(d, terms, str(path))
