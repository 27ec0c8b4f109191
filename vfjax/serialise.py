"""Models and fit results to and from plain JSON-ready dicts, without loss."""

import dataclasses
import importlib

import equinox as eqx
import numpy as np

from .model import VocalFoldModel
from .subject import Subject


def _qualname(obj) -> str:
    cls = type(obj)
    return f"{cls.__module__}:{cls.__qualname__}"


def _resolve(name: str):
    module, _, qual = name.partition(":")
    obj = importlib.import_module(module)
    for part in qual.split("."):
        obj = getattr(obj, part)
    return obj


def _value(v):
    arr = np.asarray(v)
    return arr.item() if arr.ndim == 0 else arr.tolist()


def _module_to_dict(m: eqx.Module) -> dict:
    fields = {f.name: _value(getattr(m, f.name)) for f in dataclasses.fields(m)}
    return {"class": _qualname(m), "fields": fields}


def _module_from_dict(d: dict):
    cls = _resolve(d["class"])
    return cls(**d["fields"])


def model_to_dict(model: VocalFoldModel) -> dict:
    """A model as a dict: the subject's fields, each term's class and fields, and S."""
    return {
        "subject": _module_to_dict(model.subject)["fields"],
        "terms": [_module_to_dict(t) for t in model.terms],
        "S": _value(model.S),
    }


def model_from_dict(d: dict) -> VocalFoldModel:
    """Inverse of `model_to_dict` (term classes are imported by their qualified names)."""
    terms = tuple(_module_from_dict(t) for t in d["terms"])
    return VocalFoldModel(subject=Subject(**d["subject"]), terms=terms, S=d["S"])


def fit_result_to_dict(result) -> dict:
    """A `FitResult` as a JSON-ready dict (schema: data_schema/fit_result.schema.json)."""
    out = {f.name: getattr(result, f.name) for f in dataclasses.fields(result)}
    out["model"] = None if result.model is None else model_to_dict(result.model)
    out["schema"] = "vfjax.fit_result/1"
    return out


def fit_result_from_dict(d: dict):
    """Inverse of `fit_result_to_dict`."""
    from .fit import FitResult

    d = dict(d)
    d.pop("schema", None)
    d["model"] = None if d.get("model") is None else model_from_dict(d["model"])
    return FitResult(**d)
