"""Diagnosis on the shared syn_gap case (hidden GlottalGap, a_gap = 0.01 cm²): the score
test ranks the gap first, and adding it makes the error fall and recovers its size."""

import json

import pytest

import vfjax
from vfjax import GlottalGap
from vfjax.diagnose import extend, score_tests


@pytest.fixture(scope="module")
def gap_fit(shared_dir):
    folder = shared_dir / "data" / "synthetic"
    rec = vfjax.load_recording(folder / "syn_gap.csv")
    answer = json.loads((folder / "syn_gap.answer.json").read_text())
    result = vfjax.fit(vfjax.initial_model(rec), rec, params=("S", "K", "C_f", "t_c"),
                       progress=False)  # fmt: skip
    return rec, answer, result


def test_hidden_gap_ranks_first(gap_fit):
    rec, _, result = gap_fit
    scores, level = score_tests(result, rec, effects=("GlottalGap", "CubicStiffness",
                                                      "MucosalDelay"))  # fmt: skip
    assert scores[0].effect == "GlottalGap", scores
    assert scores[0].p_value < level and scores[0].direction == +1
    assert all(s.p_value > level for s in scores[1:]), scores


def test_adding_the_gap_halves_the_error_and_recovers_it(gap_fit):
    rec, answer, result = gap_fit
    extended = extend(result, rec, GlottalGap())
    assert extended.nmse <= 0.5 * result.nmse
    truth = answer["effect_values"]["GlottalGap"]
    assert extended.params["a_gap"] == pytest.approx(truth, rel=0.2)
    assert extended.model.has(GlottalGap)
