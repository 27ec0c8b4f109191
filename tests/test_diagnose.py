"""Score tests: the hidden effect of the shared syn_gap case ranks first and is significant."""

import vfjax
from vfjax.diagnose import score_tests
from vfjax.fit import fit, initial_model


def test_hidden_gap_is_found(shared_dir):
    rec = vfjax.load_recording(shared_dir / "data" / "synthetic" / "syn_gap.csv")
    result = fit(initial_model(rec), rec, params=("S", "K", "C_f", "t_c"), progress=False)
    scores, level = score_tests(result, rec, effects=("GlottalGap", "CubicStiffness",
                                                      "MucosalDelay"))  # fmt: skip
    assert scores[0].effect == "GlottalGap", scores
    assert scores[0].p_value < level and scores[0].direction == +1
    assert all(s.p_value > level for s in scores[1:]), scores
