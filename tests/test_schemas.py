"""The schemas accept the shared data and the presets, and reject broken input by field."""

import json
import pathlib

import jsonschema
import pytest

import vfjax

SCHEMAS = pathlib.Path(__file__).parents[1] / "data_schema"


def _schema(name):
    schema = json.loads((SCHEMAS / name).read_text())
    jsonschema.Draft202012Validator.check_schema(schema)
    return schema


def test_shared_synthetic_sidecars_validate(shared_dir):
    schema = _schema("recording.schema.json")
    sidecars = [
        p
        for p in (shared_dir / "data" / "synthetic").glob("*.json")
        if not p.name.endswith(".answer.json")
    ]
    assert len(sidecars) >= 3
    for path in sidecars:
        jsonschema.validate(json.loads(path.read_text()), schema)


def test_presets_validate_as_parameter_sets():
    schema = _schema("parameters.schema.json")
    for values in vfjax.PRESETS.values():
        jsonschema.validate(values, schema)


def test_bad_sidecar_is_rejected_naming_the_field():
    schema = _schema("recording.schema.json")
    with pytest.raises(jsonschema.ValidationError, match="fps"):
        jsonschema.validate({"area_unit": "px"}, schema)
    with pytest.raises(jsonschema.ValidationError, match="-4000"):
        jsonschema.validate({"fps": -4000, "area_unit": "px"}, schema)
