"""The diagnosis: its pieces against analytic truths, and the whole loop on data with a
hidden effect (the shared independent recordings, and vfjax's own with noise and jitter).

Heavy cases (a fit + a diagnosis with six refits each) share one xdist group so that one
worker compiles each candidate's refit once; the rest of the hidden-effect matrix is marked
slow (`python -m pytest -m slow`)."""

import dataclasses
import functools
import json
import math
from typing import ClassVar

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

import vfjax
from vfjax import (
    ClosureHold,
    CubicStiffness,
    FlowSeparation,
    GlottalGap,
    MucosalDelay,
    PressureModulation,
    search_range,
)
from vfjax._diagnosis._candidates import offered
from vfjax._diagnosis._refits import NullSearch, anchor_values
from vfjax._diagnosis._score import _estimate, _hac, sensitivities
from vfjax._diagnosis._verdict import verdict_text
from vfjax.datasets import demo_recording
from vfjax.diagnosis import Candidate, bootstrap_interval, default_candidates
from vfjax.workflow import Investigation, Round


# ------------------------------------------------------------------------------ the pieces
def test_candidates_follow_the_terms_declarations():
    gap = Candidate.of(GlottalGap)
    assert (gap.tested, gap.one_sided, gap.dof, gap.point) == (("a_gap",), True, 1, {"a_gap": 0})
    pm = Candidate.of(PressureModulation)
    assert pm.tested == ("a_pm",) and pm.dof == 2 and not pm.one_sided
    assert len(pm.grid) == 19 and set(pm.extra) == {"f_m", "phi"}
    assert Candidate.of(MucosalDelay).point == {"tau": 1e-9}
    assert not Candidate.of(CubicStiffness).one_sided
    # the paper's own terms are candidates only where absent or switched off
    names = [c.name for c in default_candidates(vfjax.preset("N1"))]
    assert names == ["GlottalGap", "CubicStiffness", "PressureModulation", "MucosalDelay"]
    off = vfjax.preset("N1").with_term(FlowSeparation(fs_strength=0.0)).without(ClosureHold)
    names = [c.name for c in default_candidates(off)]
    assert names[-2:] == ["FlowSeparation", "ClosureHold"]
    # a listed candidate (investigate's, vfjax diagnose --also) is offered alike: an active
    # term is left out, one at its off-value is offered as the model's own term
    gapped = vfjax.preset("N1").with_term(GlottalGap(a_gap=0.002))
    listed = offered(
        gapped.with_term(FlowSeparation(fs_strength=0.0)),
        [GlottalGap, FlowSeparation, Candidate.of(MucosalDelay)],
    )
    assert [c.name for c in listed] == ["FlowSeparation", "MucosalDelay"]
    assert float(listed[0].term.fs_strength) == 0.0


def test_a_term_without_off_values_is_refused():
    with pytest.raises(ValueError, match="off_values"):
        Candidate.of(vfjax.Elastic)
    with pytest.raises(TypeError):
        Candidate.of(int)


#: One worker fits the true N3 model's S once for the tests below (its programs are shared).
_AT_THE_TRUTH = pytest.mark.xdist_group("n3_truth")


def _fit_at_the_truth():
    """The demo N3 recording without noise and a fit of its S alone from the true model."""
    rec = demo_recording("N3", noise_px=0.0)
    result = vfjax.fit(
        vfjax.preset("N3"), rec, params=("S",), swarm=vfjax.Swarm(iterations=0), progress=False
    )
    return rec, result


@_AT_THE_TRUTH
def test_gap_sensitivity_is_the_camera_scale(shared_dir):
    """d(observed px)/d(a_gap) = 100 S px per cm² wherever the GAW is open: analytic."""
    rec, result = _fit_at_the_truth()
    cols = sensitivities(result, [Candidate.of(GlottalGap)])[2][0][0, :, 0]
    open_ = result.fitted_gaw(rec) > 0
    assert np.allclose(cols[open_], 100.0 * result.params["S"], rtol=1e-12)


@_AT_THE_TRUTH
def test_candidates_sensitivities_from_one_extended_model():
    """All candidates' columns come from one model extended by all of them (each at its
    score point, the others off): the same as from the model extended by each alone."""
    rec, result = _fit_at_the_truth()
    cands = [Candidate.of(k) for k in (GlottalGap, PressureModulation, MucosalDelay)]
    together = sensitivities(result, cands)[2]
    assert [c.shape for c in together] == [(1, 201, 1), (38, 201, 1), (1, 201, 1)]
    for cand, cols in list(zip(cands, together))[1:]:
        alone = sensitivities(result, [cand])[2][0]
        scale = np.abs(alone).max()
        assert scale > 0
        np.testing.assert_allclose(cols, alone, rtol=0, atol=1e-8 * scale, err_msg=cand.name)


def test_hac_of_independent_scores_is_their_outer_product():
    rng = np.random.default_rng(2)
    h = rng.standard_normal((20000, 2))
    v = _hac(h, 10) / h.shape[0]
    assert np.allclose(v, np.eye(2), atol=0.06)


def test_sine_cosine_step_becomes_amplitude_and_phase():
    """A sin(wt + p) = A cos p sin(wt) + A sin p cos(wt) = c0 sin(wt + 0) + c1 sin(wt + pi/2)."""
    cand = Candidate.of(PressureModulation)
    a, p = 0.04, -2.1
    est = _estimate(cand, np.array([a * math.cos(p), a * math.sin(p)]), {"f_m": 7.0})
    assert est["a_pm"] == pytest.approx(a) and est["phi"] == pytest.approx(p)
    assert est["f_m"] == 7.0


def test_a_terms_own_search_range_is_used():
    class Drag(vfjax.AbstractForce):
        b: jnp.ndarray = eqx.field(default=0.0, converter=jnp.asarray)
        parameters: ClassVar = {"b": ("b", "g/cm")}
        off_values: ClassVar = {"b": 0.0}
        ranges: ClassVar = {"b": (0.0, 0.5, 0.02)}

        def force(self, ctx):
            return -self.b * jnp.abs(ctx.v) * ctx.v

    model = vfjax.preset("N3").with_effect(Drag())
    assert search_range(model, "b") == (0.0, 0.5, 0.02)
    assert search_range(model, "a_gap") is not None  # the catalogue's table
    assert search_range(vfjax.preset("N3"), "b") is None


def test_confirming_search_grows_with_the_candidates_parameters():
    plan = vfjax.RefitPlan(confirm_swarms=3, confirm_iterations=100)
    assert plan.confirm_search(1) == (3, 100)
    assert plan.confirm_search(3) == (12, 150)  # a modulation: depth, frequency, phase


@_AT_THE_TRUTH
def test_bad_arguments_are_refused(shared_dir):
    rec, result = _fit_at_the_truth()
    with pytest.raises(ValueError, match="alpha"):
        vfjax.Criteria(alpha=0.0)
    with pytest.raises(ValueError, match="confirm_iterations"):
        vfjax.RefitPlan(confirm_iterations=0)
    with pytest.raises(TypeError, match="confirm_polish"):
        vfjax.RefitPlan(confirm_polish=100)
    for polished in (0, 1.5, True):
        with pytest.raises(ValueError, match="polished"):
            vfjax.RefitPlan(polished=polished)
    with pytest.raises(TypeError, match="Criteria"):
        vfjax.diagnose(result, rec, criteria=0.01)
    with pytest.raises(TypeError, match="RefitPlan"):
        vfjax.diagnose(result, rec, plan=(64, 100))
    with pytest.raises(TypeError, match="Calibration"):
        vfjax.diagnose(result, rec, calibration=99)
    with pytest.raises(ValueError, match="already active"):
        vfjax.diagnose(result, rec, [ClosureHold])
    with pytest.raises(ValueError, match="variance"):
        vfjax.score_tests(result, rec, variance="robust")
    with pytest.raises(ValueError, match="variance"):
        vfjax.Criteria(variance="robust")


# ------------------------------------------------------------------- shared independent data
def _shared(shared_dir, name, **options):
    folder = shared_dir / "data" / "synthetic"
    rec = vfjax.load_recording(folder / f"{name}.csv")
    answer = json.loads((folder / f"{name}.answer.json").read_text())
    result = vfjax.fit_recording(rec, progress=False)  # as the command line's first fit
    return rec, answer, result, vfjax.diagnose(result, rec, **options)


#: A level whose smallest p-value (1/20) takes one batch of 19 null recordings (and the
#: recording) instead of the default's seven batches of 16 (1/112 at alpha 0.01), and a short
#: search: one start per candidate, no confirming refit, batches of 32 refits. Notebook 03's
#: quick run uses the same level, search and batch of null recordings (so that its kernel
#: finds these programs compiled: `tests/test_notebooks.py`), notebook 02's the same level
#: with batches of 8 refits for its one candidate. The default search runs in the slow cases and
#: in benchmarks/diagnosis_power.py.
QUICK_LEVEL = {
    "criteria": vfjax.Criteria(alpha=0.05),
    "calibration": vfjax.Calibration(replicates=19, batch=20),
    # one polish program (the intervals' replicates polished as the quick refits are)
    "plan": vfjax.RefitPlan(
        starts=1, confirm_iterations=None, confirm_polish=vfjax.Polish(max_steps=30), batch=32
    ),
}


@pytest.mark.slow  # 2 minutes; the false-alarm rate is measured in benchmarks/
@pytest.mark.xdist_group("diagnosis")  # one worker compiles the calibration's programs once
def test_shared_no_effect_case_flags_nothing(shared_dir):
    rec, answer, result, d = _shared(shared_dir, "syn_base")
    assert answer["hidden_effects"] == []
    assert d.needed == [], d.verdict
    assert d.verdict.startswith("No ")
    # the investigation's conclusion: the paper's model fits to the noise (2 px)
    outcome = Investigation(rec.name, [Round(result, d, None, None)]).outcome(rec)
    assert outcome.status == "at the noise level" and outcome.evidence == {}, outcome.words
    cal = d.calibrated
    # the uncalibrated F test calls the pressure modulation's fall significant; against
    # null recordings of the fitted model it is not, and no candidate is
    assert d.refits["PressureModulation"].f_p_value < 1e-3
    assert min(f.p_value for f in d.refits.values()) > 0.05
    # decided after the first batch: no candidate can reach alpha
    assert cal.replicates < vfjax.Calibration().replicates
    # the null recordings' noise is the answer's (2 px) and they leave an error of the
    # recording's order; a candidate's refit never ends above the control
    assert cal.variability.noise_sd == pytest.approx(answer["noise_px"], rel=0.15)
    assert 0.2 < cal.variability.simulated_control_nmse / cal.control_nmse < 2.0
    assert all(f.nmse <= c for f, c in zip(d.refits.values(), cal.controls))
    assert d.unconfirmed == [], d.verdict


@pytest.mark.xdist_group("diagnosis")
def test_shared_gap_case(shared_dir, capsys):
    rec, answer, result, d = _shared(shared_dir, "syn_gap", **QUICK_LEVEL, progress=True)
    assert d.held == {} and "Caution" not in d.verdict  # a first fit holds nothing it adjusts
    # progress: a line per candidate on stdout, the calibration's bar on stderr, counting
    # its null recordings to the most the calibration may draw
    out, err = capsys.readouterr()
    assert f"; {d.calibrated.replicates} null recordings" in out and "GlottalGap: NMSE" in out
    assert "calibrate syn_gap" in err and f"{d.calibrated.replicates}/19 [" in err, err[-500:]
    assert d.ranking[0] == "GlottalGap" and d.best == "GlottalGap", d.verdict
    assert d.scores["GlottalGap"].direction == +1
    refit = d.refits["GlottalGap"]
    assert refit.nmse <= 0.5 * d.nmse_before
    assert refit.values["a_gap"] == pytest.approx(answer["effect_values"]["GlottalGap"], rel=0.2)
    # all candidates were refitted in one batch; each refit's model carries its own only
    assert refit.result.model.has(GlottalGap)
    assert not any(refit.result.model.has(k) for k in (MucosalDelay, PressureModulation))
    assert refit.identified and refit.p_value <= d.level
    # the bootstrap interval holds the hidden value
    low, high = refit.interval["a_gap"]
    assert low <= answer["effect_values"]["GlottalGap"] <= high
    # made from the gap's values refitted on its replicates, which the record keeps (and
    # only for a candidate with an interval), on the scale of its logarithm (a positive size)
    cal = d.calibrated
    kept = cal.bootstrap_values[cal.candidates.index("GlottalGap")]
    assert len(kept["a_gap"]) == QUICK_LEVEL["calibration"].interval_replicates
    assert np.all(np.isfinite(kept["a_gap"])) and np.ptp(kept["a_gap"]) > 0
    level = QUICK_LEVEL["calibration"].interval
    made = bootstrap_interval(refit.values["a_gap"], kept["a_gap"], level, positive=True)
    assert made == (low, high)
    assert [name for name, v in zip(cal.candidates, cal.bootstrap_values) if v] == ["GlottalGap"]
    # a candidate's search run on null recordings as on the recording: given the recording
    # itself twice, in one batch, each search ends where the recording's did (within the
    # swarms' draws, which differ from one batch slot to another: 0.2 %)
    k = d.calibrated.candidates.index("MucosalDelay")
    anchor = anchor_values(result, rec)
    n_starts = [d.plan.batch] * len(d.candidates)  # (sets per_batch, not called here)
    search = NullSearch(result, rec, d.candidates, d.plan, anchor, "hac", n_starts)
    again = search(k, np.stack([rec.area, rec.area]))
    np.testing.assert_allclose(again, d.refits["MucosalDelay"].result.nmse, rtol=0.01)
    # an interval's replicates refitted by a search (`Calibration.interval_search`): from the
    # gap's refit, the recording's search ends no higher (its point starts the first swarm;
    # within 0.1 %, the swarm's single precision and its grid of time shifts) and keeps its
    # gap (the shared recording's basin). (Polished as the quick refits are: their program.)
    gap = next(c for c in d.candidates if c.name == "GlottalGap")
    fitted = refit.result.model.params()
    point = {n: float(fitted[n]) for n in (*result.params, "a_gap")}
    (searched,) = vfjax.diagnosis.refit_replicates(
        result, [rec], gap, point, d.plan, family=d.candidates, anchor=anchor
    )
    assert searched.model.has(GlottalGap) and not searched.model.has(MucosalDelay)
    assert searched.nmse <= refit.result.nmse * 1.001, (searched.nmse, refit.result.nmse)
    assert float(searched.model.term(GlottalGap).a_gap) == pytest.approx(point["a_gap"], rel=0.05)
    # the investigation's conclusion: the gap explains the recording; without it, the
    # paper's model leaves the closed phase unexplained
    added = Investigation(rec.name, [Round(result, d, "GlottalGap", refit.result)])
    outcome = added.outcome(rec)
    removed = (result.nmse - refit.result.nmse) / (result.nmse - d.noise_nmse)
    assert outcome.status == "explained" and outcome.removed == pytest.approx(removed)
    assert removed > 0.9 and outcome.evidence == {"GlottalGap": refit.p_value}
    assert "GlottalGap (calibrated p = " in outcome.words
    assert "P_s" not in outcome.words  # the fit's pressure lies within PRESSURE_RANGE
    assert "no glottal cycle" not in outcome.words  # (syn_gap vibrates throughout)
    # a recording whose glottis stops (its last 80 frames closed) is named so in the words
    stopped = dataclasses.replace(rec, area=np.where(np.arange(rec.n_frames) < 121, rec.area, 0))
    assert "has no glottal cycle in " in added.outcome(stopped).words
    # a final fit whose pressure reached the edge of the plausible range is named
    strained = dataclasses.replace(refit.result, params={**refit.result.params, "P_s": 3e4})
    words = Investigation(rec.name, [Round(result, d, "GlottalGap", strained)]).outcome(rec).words
    assert "P_s = 3e+04 dyne/cm² reaches the edge of the 1000-30000 dyne/cm² of phonation" in words
    alone = Investigation(rec.name, [Round(result, d, None, None)]).outcome(rec)
    assert alone.status == "unexplained" and alone.evidence == {}
    assert any(f.startswith("closed phase") for f in alone.failures), alone.failures
    # the paper's model without the gap leaves a misfit that repeats every cycle: its error
    # lies above every null recording's (its noise and cycle-to-cycle variability alone)
    cal = d.calibrated
    assert len(cal.null_controls) == cal.replicates == 19
    assert max(cal.null_controls) < cal.control_nmse and alone.fit_p_value == 1 / 20
    assert "is above that of all 19 null recordings" in alone.words
    assert math.isnan(outcome.fit_p_value)  # (the extended fit was not diagnosed)
    # a diagnosis of a failed fit says so first: its falls are measured from that fit
    assert not result.failed and not d.verdict.startswith("The diagnosed fit")
    no_better = dataclasses.replace(result, status="worse_than_mean", nmse_of_mean=0.02)
    text = verdict_text(dataclasses.replace(d, result=no_better))
    assert text.startswith(
        f"The diagnosed fit failed: NMSE {result.nmse:.4g} is no better than the recording's "
        "mean as a constant (0.02)"
    )
    assert "; the effects are weighed against it. " in text and "GlottalGap is missing" in text
    # a candidate whose refit ends above the refit without any effect (after a longer
    # warm-up) is named as not assessed, not read as evidence against it
    assert "Not assessed" not in d.verdict
    worse = dataclasses.replace(d.refits["MucosalDelay"], nmse=0.04, fall=-1.0)
    flagged = verdict_text(dataclasses.replace(d, refits={**d.refits, "MucosalDelay": worse}))
    assert "Not assessed: the refits with MucosalDelay (NMSE 4.000% against 2.000%)" in flagged
    # the search refits that would explain the recording are put to the calibrated test
    # too (the gap's, at least); none is flagged: the gap is needed, the others do not pass
    assert 0 < refit.search_p_value <= d.level
    assert all(math.isnan(f.search_p_value) or 0 < f.search_p_value <= 1 for f in d.refits.values())
    assert d.unconfirmed == [] and "Unconfirmed" not in d.verdict
    # a search refit that passes where its calibrated refit does not is named unconfirmed, in
    # the verdict and in the investigation's words, and is neither needed nor ruled out
    delay = d.refits["MucosalDelay"]
    searched = dataclasses.replace(delay.result, nmse=0.001)
    found = dataclasses.replace(
        delay, p_value=1.0, search_p_value=1 / 20, nmse=0.04, result=searched
    )
    nothing = dataclasses.replace(d, needed=[], refits={**d.refits, "MucosalDelay": found})
    assert nothing.unconfirmed == ["MucosalDelay"] and nothing.needed == []
    text = verdict_text(nothing)
    assert text.startswith("No ") and "Unconfirmed: the search's refits with MucosalDelay" in text
    assert "Yet the fit's error is above that of all 19 null recordings" in text
    tau = float(delay.result.model.term(MucosalDelay).tau)
    assert f"(NMSE 0.100% against 4.000%; tau = {tau:.4g})" in text
    words = Investigation(rec.name, [Round(result, nothing, None, None)]).outcome(rec).words
    assert "the search's refits with MucosalDelay fit better but are unconfirmed" in words
    # searched alike on too few of the null recordings to decide: the verdict says how to
    # decide it (all of them searched)
    cal, n = d.calibrated, d.calibrated.replicates
    few = tuple(5 if c == "MucosalDelay" else 0 for c in cal.candidates)
    some = dataclasses.replace(nothing, calibrated=dataclasses.replace(cal, searched_nulls=few))
    assert (
        "searched alike, 5 of the null recordings fell short of it, too few to decide "
        f"(searching all {n} decides it, at a search per null recording: "
        "vfjax.Calibration(search_nulls=None), vfjax diagnose --search-nulls all)"
    ) in verdict_text(some)
    assert "searching all" not in verdict_text(nothing)  # (not searched alike: no count)


@pytest.mark.slow
def test_shared_gap_case_second_round_finds_nothing(shared_dir):
    rec, _, _, d = _shared(shared_dir, "syn_gap")
    d2 = vfjax.diagnose(d.refits["GlottalGap"].result, rec)
    assert d2.needed == [], d2.verdict


@pytest.mark.slow  # about 3 minutes: the command line's defaults on two CPU devices
def test_the_command_line_adds_the_shared_gap_at_the_default_level(shared_dir, tmp_path, cli):
    """`vfjax diagnose` of the shared syn_gap as a user runs it: alpha 0.01, up to 111 null
    recordings, the default search, two CPU devices (the statistic split over them, which
    rounds otherwise than one device). Its final fit carries the hidden gap, within 20 %."""
    folder = shared_dir / "data" / "synthetic"
    answer = json.loads((folder / "syn_gap.answer.json").read_text())
    out = tmp_path / "d"
    run = cli("diagnose", folder / "syn_gap.csv", "--out", out, timeout=900, VFJAX_CORES="2")
    assert run.returncode == 0, run.stderr[-2000:]
    final = vfjax.FitResult.from_json(out / "syn_gap_final_fit.json")
    assert final.model.has(GlottalGap), run.stdout
    a_gap = float(final.model.term(GlottalGap).a_gap)
    assert a_gap == pytest.approx(answer["effect_values"]["GlottalGap"], rel=0.2)


@pytest.mark.slow
@pytest.mark.xdist_group("diagnosis")
@pytest.mark.xfail(
    strict=True,
    reason="a modulation that switches closures (first fit NMSE 17.9 %): the calibrated "
    "refits from fixed starts miss the search's basin (NMSE 0.55 %), so the diagnosis names "
    "the modulation unconfirmed, not needed (benchmarks/README.md, 'A modulation that "
    "switches closures')",
)
def test_shared_tremor_case(shared_dir):
    _, answer, _, d = _shared(shared_dir, "syn_tremor")
    assert d.ranking[0] == "PressureModulation" and d.best == "PressureModulation", d.verdict
    refit = d.refits["PressureModulation"]
    assert refit.nmse <= 0.5 * d.nmse_before
    depth, frequency, _ = answer["effect_values"]["PressureModulation"]
    # P_s is fitted (the recording does not state it): the GAW fixes the modulation's
    # amplitude in dyne/cm², a_pm P_s, rather than its share of a pressure it does not fix
    amplitude = refit.values["a_pm"] * refit.result.params["P_s"]
    truth = depth * answer["true_params"]["Ps_dyn_per_cm2"]
    assert amplitude == pytest.approx(truth, rel=0.2)
    # 50 ms hold a third of the 7 Hz modulation's period: refits at f_m fixed anywhere in
    # 6-8.3 Hz reach the same NMSE within the noise (5 and 9.5 Hz do not), so the frequency
    # is held to a looser 30 %
    assert refit.values["f_m"] == pytest.approx(frequency, rel=0.3)


# -------------------------------------------------------------- vfjax's own hidden effects
N_FRAMES = 401
CASES = {
    # name: (preset, hidden term or None, paper term removed from the fitted model, truth)
    "none": ("N1", None, None, None),
    "GlottalGap": ("N3", GlottalGap(a_gap=0.008), None, ("a_gap", 0.008)),
    "CubicStiffness": ("N1", CubicStiffness(eta=3000.0), None, ("eta", 3000.0)),
    "PressureModulation": (
        "N1",  # at N1's pressure the modulation switches closure on and off (as syn_tremor's)
        PressureModulation(a_pm=0.08, f_m=10.0, phi=1.0),
        None,
        ("a_pm", 0.08),
    ),
    "MucosalDelay": ("N3", MucosalDelay(tau=4e-4), None, ("tau", 4e-4)),
    # the flow separation's strength trades off against C_f along a flat valley (from the
    # truth, LM walks to fs_strength 1.8, C_f x1.75 at an equal NMSE): the GAW fixes their
    # ratio, which is what comes back (N1: C_f large enough to pin it within a few %)
    "FlowSeparation": ("N1", None, FlowSeparation, ("fs_strength / C_f", 1.0 / 7536.2)),
    "ClosureHold": ("N1", None, ClosureHold, ("t_c", None)),
}
#: what comes back, where it is not one parameter
_RECOVERED = {"fs_strength / C_f": lambda p: p["fs_strength"] / p["C_f"]}
DEFAULT = ()  # the whole matrix is slow (about 2 minutes a case); run with -m slow


@functools.cache  # the no-effect case serves two tests
def _hidden_case(case):
    name, effect, dropped, truth = CASES[case]
    rec = demo_recording(
        name, effect=effect, jitter=0.003, seed=3, n_frames=N_FRAMES, name_suffix=f"_{case}"
    )
    start = vfjax.initial_model(rec)
    params = ("S", "K", "C_f", "t_c")
    if dropped is not None:
        start = start.without(dropped)
        params = tuple(p for p in params if p in start.parameter_units())
    result = vfjax.fit(start, rec, params=params, progress=False)
    return rec, result, vfjax.diagnose(result, rec), truth


#: cases the diagnosis is known to miss, with why
_MISSED = {
    "PressureModulation": "a modulation that switches closures, as syn_tremor's: the first fit "
    "stops at NMSE 58 %, above the recording's mean as a constant (50 %), and the refit with "
    "the modulation misses its basin (60 %), so nothing is named (benchmarks/README.md, 'A "
    "modulation that switches closures')",
}


def _marks(case):
    marks = [] if case in DEFAULT else [pytest.mark.slow]
    if case in _MISSED:
        marks.append(pytest.mark.xfail(strict=True, reason=_MISSED[case]))
    return marks


@pytest.mark.xdist_group("diagnosis")
@pytest.mark.parametrize("case", [pytest.param(c, marks=_marks(c)) for c in CASES])
def test_hidden_effect_is_found(case):
    rec, result, d, truth = _hidden_case(case)
    if case == "none":
        assert d.needed == [], d.verdict
        return
    assert d.ranking[0] == case and d.best == case, d.verdict
    refit = d.refits[case]
    assert refit.nmse <= max(0.5 * d.nmse_before, 2.0 * d.noise_nmse)
    if truth is not None:
        name, value = truth
        if value is None:  # the hold: the preset's own t_c
            value = float(vfjax.preset(CASES[case][0]).params()[name])
        found = refit.result.params
        got = _RECOVERED[name](found) if name in _RECOVERED else found[name]
        assert got == pytest.approx(value, rel=0.2), (name, found)


@pytest.mark.slow
@pytest.mark.xdist_group("diagnosis")
def test_a_recording_without_an_effect_names_nothing_unconfirmed():
    """The modulation's search fits part of the no-effect recording's cycle-to-cycle
    variability and passes against the null recordings' refits from fixed starts; searched
    alike, a null recording's search falls as far, which rules it out."""
    _, _, d, _ = _hidden_case("none")
    assert d.unconfirmed == [] and d.needed == [], d.verdict
    cal = d.calibrated
    for k, name in enumerate(cal.candidates):
        refit = d.refits[name]
        if cal.searched_nulls[k]:  # searched alike, and ruled out
            assert refit.search_p_value > d.criteria.alpha
            assert refit.search_p_value >= 1 / (1 + cal.searched_nulls[k])


@pytest.mark.xdist_group("paper_fit")  # the paper model's S, K, C_f fit: compiled once
def test_score_only_diagnosis_and_its_report(tmp_path, report_html):
    """Without refits the ranking is by score p-value; the report is written with its
    figures and names every candidate (hidden gap, N3, 1 px noise: the gap ranks first);
    `diagnosis.extend` adds the gap and recovers it."""
    rec = demo_recording("N3", noise_px=1.0, effect=GlottalGap(a_gap=0.008))
    result = vfjax.fit(
        vfjax.preset("N3"),
        rec,
        params=("S", "K", "C_f"),
        swarm=vfjax.Swarm(iterations=20),
        progress=False,
    )
    d = vfjax.diagnose(result, rec, plan=None)
    assert d.refits == {} and d.control is None
    assert d.ranking[0] == "GlottalGap" and d.scores["GlottalGap"].direction == +1
    # the fit held the closure duration, which a first fit adjusts (the recording states its
    # pressure, which is held alike); where an effect is named, the verdict says that it may
    # stand in for the closure duration
    t_c = float(result.model.params()["t_c"])
    assert d.held == {"t_c": (t_c, "s")}
    assert d.needed == [] and "Caution" not in d.verdict
    named = verdict_text(dataclasses.replace(d, needed=["GlottalGap"]))
    assert named.startswith("GlottalGap is missing")
    assert f"Caution: the diagnosed fit held t_c at {t_c:.4g} s, where a first fit" in named
    assert "an effect found here may stand in for it. Diagnose a first fit to tell." in named
    path = vfjax.report.write_report(d, rec, tmp_path)
    text = path.read_text()
    for name in d.ranking:
        assert f"| {name} |" in text
    # nothing added: the paper's model leaves the gap's closed phase unexplained
    assert "**Outcome: unexplained.** No catalogue effect is needed" in text
    assert "closed phase: the measured area never falls below" in text
    assert (tmp_path / f"{rec.name}_rounds.png").stat().st_size > 1000
    assert (tmp_path / f"{rec.name}_round1_compare.png").exists()
    # the same report as one self-contained HTML page, figures embedded
    page = report_html(path)
    assert "closed phase: the measured area never falls below" in page
    # with edges (a glottis of 10 rows, symmetric about column 50) the report gives the
    # asymmetry indices of symmetric folds
    half = np.repeat(rec.area[:, None], 10, axis=1) / 20.0
    sided = dataclasses.replace(rec, edges=np.stack([50.0 - half, 50.0 + half], axis=1), folds=None)
    text = vfjax.report.write_report(d, sided, tmp_path / "sided").read_text()
    assert "ASI 1.000, phase asymmetry index PAI 0.000" in text
    # the plain API: add the effect to the fitted model and refit from the current fit
    extended = vfjax.diagnosis.extend(result, rec, GlottalGap(), swarm=vfjax.Swarm(iterations=20))
    assert extended.model.has(GlottalGap)
    assert extended.nmse < 0.5 * result.nmse
    assert extended.params["a_gap"] == pytest.approx(0.008, rel=0.2)

    # an investigation that added nothing ends with its last diagnosis's control refit where
    # that fit the same model better (and says so in the report), else with the fit itself
    def study_with(control):
        last = vfjax.workflow.Round(result, dataclasses.replace(d, control=control), None, None)
        return vfjax.Investigation(rec.name, [last])

    better = dataclasses.replace(result, nmse=0.5 * result.nmse)
    assert study_with(better).final is better
    assert study_with(dataclasses.replace(result, nmse=2.0 * result.nmse)).final is result
    assert study_with(None).final is result
    text = vfjax.report.write_report(study_with(better), rec, tmp_path / "refitted").read_text()
    assert f"| {better.nmse:.3%} | |" in text


# ----------------------------------------------------- the calibration's two sides, slow
def _diagnosed(rec):
    result = vfjax.fit_recording(rec, progress=False)
    return vfjax.diagnose(result, rec)


@pytest.mark.slow
def test_strong_cycle_to_cycle_variability_alone_is_not_flagged():
    # N3 whose stiffness varies by 2 % and closure by 2 % from cycle to cycle: a kind of
    # variability the null recordings do not simulate (they draw timing and amplitude
    # jitter), with no catalogue effect
    model = vfjax.preset("N3")
    period = (
        1.0
        / vfjax.descriptors.describe(np.asarray(vfjax.simulate(model, 4000.0, 400).area), 4000.0).f0
    )
    jittered = model.with_term(vfjax.StiffnessJitter.random(0.02, period, seed=3))
    rec = vfjax.datasets.demo_recording("N3", model=jittered, jitter=0.02, seed=3)
    assert (
        vfjax.descriptors.describe(rec.area, rec.fps).jitter > 0.005
    )  # the variability is visible
    d = _diagnosed(rec)
    assert d.needed == [] and d.unconfirmed == [], d.verdict


@pytest.mark.slow  # two minutes
def test_a_recording_at_its_noise_keeps_its_timing_wander_in_the_null_recordings():
    """N4 in sustained phonation (201 frames at 4 kHz, 1 px) with 0.3 % closure jitter and
    no catalogue effect: the first fit's cycle-to-cycle misfit lies within what noise alone
    leaves, yet the closures' jitter makes the timing wander over the cycles, which a slow
    pressure modulation fits. The null recordings carry that wander (a period spread), so
    nothing is flagged."""
    rec = vfjax.datasets.demo_recording("N4", 1.0, 6, 4000.0, 201, jitter=0.003, warmup=0.5)
    d = _diagnosed(rec)
    assert d.calibrated.variability.period_sd > 0
    assert d.needed == [] and d.unconfirmed == [], d.verdict


@pytest.mark.slow
def test_a_weak_mucosal_delay_is_flagged():
    # a delay of 0.25 ms, whose refit reaches the noise floor: no threshold on the error
    # fall keeps it from being found. N1 (male, about 34 frames a cycle at 4 000 fps): the
    # noise is estimated on open phases of more than five frames, which N3's pulses at this
    # frame rate barely have (there a misfit of the pulse inflates the estimate)
    rec = vfjax.datasets.demo_recording(
        "N1", effect=MucosalDelay(tau=0.25e-3), jitter=0.003, seed=11, name_suffix="_delay"
    )
    d = _diagnosed(rec)
    assert d.best == "MucosalDelay", d.verdict
    assert d.refits["MucosalDelay"].values["tau"] == pytest.approx(0.25e-3, rel=0.2)


@pytest.mark.slow  # about 7 minutes: the default level, 111 null recordings
def test_a_modulation_that_switches_closures_is_not_missed_silently():
    """N1 with a 20 % pressure modulation at 8 Hz, recorded 0.5 s after the onset with the
    injection-recovery benchmark's variability (seed 1, 1 px): the lower pressure stops the
    folds from opening for several cycles, which the paper's model cannot follow (first fit
    NMSE about 24 %). The search's refit with the modulation removes nearly all of it, in a
    basin so narrow that the calibrated refits from fixed starts do not reach it: the
    diagnosis must name the modulation needed or unconfirmed, never nothing."""
    fps, n_frames, warmup, seed = 4000.0, 201, 0.5, 1
    model = vfjax.preset("N1").with_effect(PressureModulation(a_pm=0.2, f_m=8.0, phi=-0.3))
    area = np.asarray(vfjax.simulate(model, fps, 400, t_start=0.05).area)
    period = 1.0 / vfjax.descriptors.fundamental_frequency(area, fps)
    covered = vfjax.datasets.factors_duration(warmup + n_frames / fps, period)
    jittered = model.with_term(
        vfjax.TimingJitter.random(30e-6, period, duration=covered, seed=seed + 11)
    ).with_term(vfjax.AmplitudeJitter.random(0.02, period, duration=covered, seed=seed + 23))
    rec = demo_recording("N1", noise_px=1.0, seed=seed, jitter=0.003, model=jittered, warmup=warmup)
    first = vfjax.fit_recording(rec, progress=False)
    d = vfjax.diagnose(first, rec)
    assert "PressureModulation" in d.needed + d.unconfirmed, d.verdict
    assert d.refits["PressureModulation"].result.nmse < 0.1 * first.nmse, d.verdict


def test_an_effect_is_identified_only_by_a_measured_interval_that_excludes_its_off_value():
    """Each tested parameter's interval must be finite, of positive width (bootstrap refits
    that all stay at the estimate measure nothing) and exclude the off-value."""
    refit = vfjax.diagnosis.EffectRefit(
        effect="GlottalGap",
        result=None,
        nmse=0.001,
        fall=0.5,
        values={"a_gap": 0.004},
        p_value=0.005,
        f_p_value=1e-6,
        marginal_p_value=0.005,
        interval={"a_gap": (0.003, 0.005)},
        off_values={"a_gap": 0.0},
    )
    assert refit.identified
    for interval in ((-0.001, 0.005), (0.004, 0.004), (math.nan, math.nan)):
        assert not dataclasses.replace(refit, interval={"a_gap": interval}).identified, interval
    assert not dataclasses.replace(refit, interval=None).identified
