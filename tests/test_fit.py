"""Fitting against truths the fit did not make: known parameters, and the shared synthetic case."""

import dataclasses
import json
import pathlib
import re

import equinox as eqx
import jax
import jsonschema
import numpy as np
import pytest

import vfjax
from vfjax import Polish, Swarm, fit, fit_many
from vfjax._fit._first import _settled_or_first
from vfjax._fit._settling import settlings
from vfjax.presets import PRESSURE_KEY
from vfjax.recording import Recording, load_recording

FPS = 4000.0


def _recording(model, t_start, noise_px=0.0, seed=0, name="sim"):
    sim = vfjax.simulate(model, FPS, 201, t_start=t_start)
    area = np.clip(np.asarray(sim.area), 0, None)
    if noise_px:
        area = np.clip(area + np.random.default_rng(seed).normal(0, noise_px, area.size), 0, None)
    return Recording(area=area, fps=FPS, name=name)


def _start(truth):
    p = truth.params()
    return truth.set(K=p["K"] * 1.3, C_f=p["C_f"] * 0.6, S=30.0)


def _rel_errors(result, truth):
    p = truth.params()
    return {n: abs(result.params[n] / float(p[n]) - 1.0) for n in ("S", "K", "C_f")}


#: The tests of `n1_fit` run on one worker, which computes the fixture once.
_WITH_N1_FIT = pytest.mark.xdist_group("n1_fit")


@pytest.fixture(scope="module")
def n1_fit():
    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.0312)  # an arbitrary point of the cycle
    return truth, rec, fit(_start(truth), rec, progress=False)


@_WITH_N1_FIT
def test_recovers_parameters_without_noise(n1_fit):
    truth, _, result = n1_fit
    errs = _rel_errors(result, truth)
    assert max(errs.values()) < 0.01, errs
    assert result.nmse < 1e-6


@_WITH_N1_FIT
def test_polish_never_worse_than_the_swarm(n1_fit):
    _, _, result = n1_fit
    assert np.all(np.diff(result.pso_trace) <= 0)
    assert len(result.lm_trace) == 2 and result.lm_trace[1] <= result.lm_trace[0]
    # the swarm's best, re-evaluated as the polish's start (same point, another code path:
    # equal to rounding)
    assert result.lm_trace[0] <= result.pso_trace[-1] * (1 + 1e-6)
    assert result.nmse == result.lm_trace[-1]
    assert result.optimistix_result in ("successful", "max_steps_reached")


@_WITH_N1_FIT
def test_fitted_gaw_reproduces_the_recording(n1_fit):
    _, rec, result = n1_fit
    gaw = result.fitted_gaw(rec)
    nmse = np.sum((gaw - rec.area) ** 2) / np.sum(rec.area**2)
    assert nmse == pytest.approx(result.nmse, rel=1e-6, abs=1e-12)


def test_recovers_parameters_with_2px_noise():
    truth = vfjax.preset("N3")
    rec = _recording(truth, t_start=0.0277, noise_px=2.0, seed=3)
    result = fit(_start(truth), rec, progress=False)
    errs = _rel_errors(result, truth)
    assert max(errs.values()) < 0.05, errs


def test_shared_syn_base_fit_reaches_the_true_parameters_error(shared_dir):
    """NMSE of the fit <= 1.1 x the NMSE of the true parameters (each with its best time
    shift; the truth's S held at its value)."""
    folder = shared_dir / "data" / "synthetic"
    rec = load_recording(folder / "syn_base.csv")
    tp = json.loads((folder / "syn_base.answer.json").read_text())["true_params"]
    truth = vfjax.paper_model(
        K_N_per_m=tp["K_N_per_m"],
        C_f_g_per_s=tp["Cf"],
        S_px_per_mm2=tp["S_px_per_mm2"],
        t_c_s=tp["t_c_s"],
        P_s_dyne_per_cm2=tp["Ps_dyn_per_cm2"],
        mass_g=tp["M_g"],
        length_cm=tp["l_cm"],
    )
    s = tp["S_px_per_mm2"]
    at_truth = fit(
        truth,
        rec,
        params=("S",),
        bounds={"S": (s * (1 - 1e-9), s * (1 + 1e-9))},
        swarm=Swarm(iterations=20),
        polish=None,
        progress=False,
    )
    result = fit(vfjax.preset("N1"), rec, progress=False)
    assert result.nmse <= 1.1 * at_truth.nmse, (result.nmse, at_truth.nmse)
    assert at_truth.params["S"] == pytest.approx(s, rel=1e-6)


def test_same_key_same_result_and_callback():
    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.03)
    seen = []
    start = truth.set(K=1.3 * float(truth.params()["K"]))  # the swarm has work to do
    kw = dict(swarm=Swarm(size=16, iterations=10, chunk=4), polish=None, progress=False)
    a = fit(start, rec, key=jax.random.key(7), callback=lambda i, c: seen.append((i, c)), **kw)
    b = fit(start, rec, key=jax.random.key(7), **kw)
    c = fit(start, rec, key=jax.random.key(8), **kw)
    assert a.params == b.params and a.pso_trace == b.pso_trace
    assert a.pso_trace != c.pso_trace
    # a raw key (jax.random.PRNGKey, two uint32 words) is that key, not two keys of one word
    raw = fit(start, rec, key=jax.random.PRNGKey(7), **kw)
    assert raw.params == a.params and raw.pso_trace == a.pso_trace
    with pytest.raises(TypeError, match="jax.random key"):
        fit(start, rec, key=np.arange(3.0), **kw)
    # after each compiled chunk of 4 evaluations: the initial swarm (iteration 0), 1-3, ...
    assert [i for i, _ in seen] == [3, 7, 10]
    assert len(a.pso_trace) == 11
    assert seen[-1][1] == a.pso_trace[-1]


@_WITH_N1_FIT
def test_json_round_trip_without_loss(n1_fit, tmp_path):
    _, rec, result = n1_fit
    path = tmp_path / "fit.json"
    result.to_json(path)
    schema = json.loads(
        (pathlib.Path(vfjax.__file__).parent / "schemas" / "fit_result.schema.json").read_text()
    )
    jsonschema.validate(json.loads(path.read_text()), schema)
    back = vfjax.FitResult.from_json(path)
    for f in (
        "params",
        "units",
        "time_shift",
        "nmse",
        "pso_trace",
        "lm_trace",
        "timings",
        "n_simulations",
        "optimistix_result",
        "sampling",
        "bounds",
        "swarm",
        "recording_name",
    ):
        assert getattr(back, f) == getattr(result, f), f
    assert back.model.params().keys() == result.model.params().keys()
    for k, v in result.model.params().items():
        assert float(back.model.params()[k]) == float(v)
    np.testing.assert_array_equal(back.fitted_gaw(rec), result.fitted_gaw(rec))


def test_fit_many_matches_single_fits():
    """Three recordings of known K, and a fourth fitted with C_f held at its true value: one
    batch, each fit recovers its truth; the held parameter stays put and is not reported."""
    truth = vfjax.preset("N1")
    factors = [0.9, 1.0, 1.1, 1.05]
    recs = [
        _recording(truth.set(K=truth.params()["K"] * f), t_start=0.03 + 0.001 * i, name=f"r{i}")
        for i, f in enumerate(factors)
    ]
    c_f = float(truth.params()["C_f"])
    models = [_start(truth)] * 3 + [_start(truth).set(C_f=c_f)]
    # a small swarm: the polish takes each fit from the swarm's best to its truth
    results = fit_many(
        models, recs, hold=[(), (), (), ("C_f",)], swarm=Swarm(size=12, iterations=10)
    )
    for f, r in zip(factors, results):
        assert r.params["K"] / float(truth.params()["K"]) == pytest.approx(f, rel=0.01)
        assert r.params["S"] == pytest.approx(43.7988, rel=0.01)
        assert r.nmse < 1e-4
    for rec, r in zip(recs, results):  # the reported NMSE is that of the fitted GAW, re-simulated
        assert r.nmse == pytest.approx(float(vfjax.nmse(rec.area, r.fitted_gaw(rec))), rel=1e-9)
    assert "C_f" not in results[3].params and "C_f" not in results[3].bounds
    assert float(results[3].model.params()["C_f"]) == c_f
    with pytest.raises(ValueError, match="held"):
        fit_many(models[0], recs[:1], hold=[("S",)])


def _problem(model, rec, params=("S", "K", "C_f")):
    from vfjax._fit._problem import fit_sampling, prepare

    sampling, period = fit_sampling(rec, 0.02, 4)
    return prepare(model, rec, params, sampling, period, None)[0]


def test_swarm_cost_is_the_best_shift_of_direct_simulations():
    """The swarm reads every time shift off one simulation; each candidate shift, simulated
    directly with that delay, gives the same cost, and none does better. The swarm's
    simulation is integrated in single precision (`integrate_window_single`): the costs
    agree to its rounding, far below any difference between fits."""
    truth = vfjax.preset("N3")
    rec = _recording(truth, t_start=0.0237, noise_px=1.0)
    problem = _problem(_start(truth), rec)
    assert problem.names == ("K", "C_f", "t_c", "P_s")  # t_c and P_s held
    z = np.array([0.1, -0.2, 0.0, 0.0])
    cost, shift, s = eqx.filter_jit(lambda p, z: p.profile(z))(problem, z)
    shape = eqx.filter_jit(lambda p, zz: p.shape(zz))  # one program for every shift
    direct = []
    max_shift = float(problem.grid.max_time_shift)
    for j in range(problem.n_shifts):
        if j / (2 * FPS) > max_shift:
            break
        zz = np.r_[z, j / (2 * FPS) / float(problem.period)]
        g, _, ok = shape(problem, zz)
        assert ok
        g = np.asarray(g)[: rec.n_frames]
        s = np.clip(rec.area @ g / (g @ g), *np.asarray(problem.s_bounds))  # closed form
        direct.append(float(np.sum((rec.area - s * g) ** 2)))
    direct = np.array(direct) / float(np.sum(rec.area**2))
    assert len(direct) > 2 * FPS * 0.005  # shifts over more than a cycle were tried
    assert float(cost) == pytest.approx(direct.min(), rel=1e-5)
    assert round(float(shift * problem.period) * 2 * FPS) == int(np.argmin(direct))
    y, start_cost = eqx.filter_jit(lambda p, z: p.start(z))(problem, z)
    r = eqx.filter_jit(lambda p, y: p.residual(y))(problem, y)
    assert float(np.sum(r**2)) == pytest.approx(float(start_cost), rel=1e-5)


def test_swarm_start_is_a_latin_hypercube_with_the_bits_of_xlas_default_compilation():
    """`_swarm_start` is compiled at LLVM's -O2, faster than XLA's default -O3: its bits
    must be the default's, or every fit's swarm would start elsewhere. Each fit's particles
    form a Latin hypercube of its box (one particle in each of n equal slices of every
    coordinate), particle 0 at the starting point (0, clipped into the box)."""
    from vfjax._fit._engine import _swarm_start

    n_fits, d = 4, 6
    rng = np.random.default_rng(3)
    lowers = -rng.uniform(0.5, 2.0, (n_fits, d))
    uppers = rng.uniform(0.5, 2.0, (n_fits, d))
    keys = jax.vmap(lambda i: jax.random.fold_in(jax.random.key(11), i))(np.arange(n_fits))
    swarm = Swarm()
    fast = _swarm_start(lowers, uppers, keys, swarm, 2)
    default = eqx.filter_jit(_swarm_start.__wrapped__)(lowers, uppers, keys, swarm, 2)

    def bits(tree):
        return [
            np.asarray(
                jax.random.key_data(x) if jax.dtypes.issubdtype(x.dtype, jax.dtypes.prng_key) else x
            )
            for x in jax.tree.leaves(tree)
        ]

    for a, b in zip(bits(fast), bits(default), strict=True):
        np.testing.assert_array_equal(a, b)
    position = np.asarray(fast.position)
    assert position.shape == (n_fits, swarm.size, d)
    np.testing.assert_array_equal(position[:, 0], 0.0)
    cells = np.floor((position[:, 1:] - lowers[:, None]) / (uppers - lowers)[:, None] * swarm.size)
    for fit_cells in cells:  # particle 0's cell is taken by the start; the rest are distinct
        for column in fit_cells.T:
            assert len(set(column)) == swarm.size - 1 and column.min() >= 0


def test_lm_linearisation_is_the_residuals_jacobian():
    """The polish sees the residual through a rule that hands it the Jacobian matrix: equal
    to forward-mode AD of the residual itself, and to central finite differences."""
    from vfjax._fit._polish import residual

    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.031)
    problem = _problem(_start(truth), rec)
    # K, C_f, the held t_c and P_s, the time shift and log S
    y = np.array([-0.2, 0.3, 0.0, 0.0, 0.4, -0.1])
    jac = np.asarray(eqx.filter_jit(jax.jacfwd(residual))(y, problem))
    assert not jac[:, 2:4].any() and np.all(np.linalg.norm(jac[:, [0, 1, 4, 5]], axis=0) > 0)
    direct = eqx.filter_jit(lambda y, p: jax.jacfwd(p.residual)(y))(y, problem)
    np.testing.assert_allclose(jac, np.asarray(direct), rtol=1e-10, atol=1e-14)
    h = 1e-6
    at = eqx.filter_jit(lambda y, p: p.residual(y))
    for i in range(y.size):
        e = np.eye(y.size)[i] * h
        fd = (np.asarray(at(y + e, problem)) - np.asarray(at(y - e, problem))) / (2 * h)
        assert np.linalg.norm(jac[:, i] - fd) <= 0.02 * np.linalg.norm(fd), i
    # a refit's basis as the diagnosis's statistic builds it: physical rows (one moving the
    # time shift too), the time shift, log S and a zero row of padding; the shift and S are
    # differentiated through the sampling alone, the rest through the integration, and each
    # column is the derivative along its row
    basis = np.zeros((5, y.size))
    basis[0, 0] = basis[2, 4] = basis[3, 5] = 1.0
    basis[1, [1, 4]] = (1.0, 0.5)
    r, columns = eqx.filter_jit(lambda y, b, p: p.residual_and_jacobian(y, b))(y, basis, problem)
    np.testing.assert_allclose(r, np.asarray(at(y, problem)), rtol=1e-12, atol=1e-15)
    np.testing.assert_allclose(columns, np.asarray(direct) @ basis.T, rtol=1e-10, atol=1e-14)
    assert not np.asarray(columns)[:, 4].any()


def _compilations():
    """The names of new programs, from JAX's monitoring events (each is lowered to MLIR,
    then compiled or loaded from the persistent compilation cache), as they come."""
    seen = []
    jax.monitoring.register_event_duration_secs_listener(
        lambda event, duration, **kw: (
            seen.append(kw.get("fun_name", ""))
            if event == "/jax/core/compile/jaxpr_to_mlir_module_duration"
            else None
        )
    )
    return seen


def test_a_new_length_and_frame_rate_compile_nothing_new():
    """After one fit, recordings of other lengths (same bucket), frame rates and f0 get their
    starting models and their fits through the same compiled programs: no compilation at
    all, at 6 kHz as at 2 kHz (8 RK4 steps a frame where the first fit took 4); nor do fits
    of other parameters of the paper's model (the closure duration from 0, in a linear
    coordinate, and the pressure), which run the same programs. A recording of a new length
    bucket compiles the fit's swarm and polish programs and no other."""
    truth = vfjax.preset("N3")
    swarm = Swarm(size=8, iterations=4, chunk=4)
    polish = Polish(max_steps=3)
    first = _recording(truth, t_start=0.0277, name="first")
    others = []
    for fps, n, f in ((6000.0, 170, 0.8), (2000.0, 130, 0.6)):  # 2 kHz: 22 cycles, not long
        sim = vfjax.simulate(truth.set(K=f * float(truth.params()["K"])), fps, n, t_start=0.03)
        others.append(Recording(area=np.clip(np.asarray(sim.area), 0, None), fps=fps, name=str(n)))
    second = others[0]
    assert {vfjax.length_bucket(r.n_frames) for r in others} == {vfjax.length_bucket(201)}
    assert first.n_frames == 201 and first.fps == 4000.0
    fit(truth, first, swarm=swarm, polish=polish, progress=False)
    vfjax.initial_model(first)  # its f0 matching simulates 512 frames or more
    seen = _compilations()
    start = len(seen)
    for rec in others:
        vfjax.initial_model(rec)
        result = fit(truth, rec, swarm=swarm, polish=polish, progress=False, warmup=0.03)
        assert len(seen) == start, f"{rec.fps:g} Hz: new programs {seen[start:]}"
        assert result.sampling.fps == rec.fps and result.sampling.n_frames == rec.n_frames
        assert np.isfinite(result.nmse) and result.nmse < result.nmse_of_mean
    assert result.sampling.substeps == 8
    for params, model in (
        (("S", "K"), truth),
        (("S", "K", "C_f", "t_c", "P_s"), truth.set(t_c=0.0)),
        (("S", "P_s", "t_c"), truth),
    ):
        other = fit(model, second, params, swarm=swarm, polish=polish, progress=False)
        assert set(other.params) == set(params) and other.nmse < other.nmse_of_mean
    assert len(seen) == start, f"{len(seen) - start} new compilations"
    jax.jit(lambda x: x * 3.0 + 1.0)(np.arange(3.0))  # the counter sees a new program
    assert len(seen) == start + 1
    # a recording of a new length bucket compiles the fit's swarm and polish programs and
    # nothing else: its batch's arrays are stacked, cut and placed on the host
    short = Recording(area=first.area[:101], fps=first.fps, name="short")
    assert vfjax.length_bucket(short.n_frames) != vfjax.length_bucket(first.n_frames)
    fit(truth, short, swarm=swarm, polish=polish, progress=False)
    # (each is lowered more than once: traced, exported and stored, then run from the store)
    new = {re.sub(r"^jit\((.*?)(_stored)?\)$", r"\1", name) for name in seen[start + 1 :]}
    assert new == {"_polish_batch", "_swarm_chunk"}, seen[start + 1 :]


def test_first_fits_of_recordings_stating_their_pressure_or_not_share_a_batch():
    """A recording that states its subglottal pressure and one that does not are first-fitted
    in one batch: the first holds P_s at the stated value, the second searches it, and each
    fit equals its fit alone."""
    truth = vfjax.preset("N3")
    low = truth.set(P_s=0.7 * float(truth.params()["P_s"]))
    female = {"sex": "female"}
    quiet = _recording(low, t_start=0.0291, noise_px=1.0)
    quiet = Recording(area=quiet.area, fps=FPS, metadata=female, name="unstated")
    stated = _recording(truth, t_start=0.0301, noise_px=1.0)
    pressure = {**female, PRESSURE_KEY: float(truth.params()["P_s"])}
    stated = Recording(area=stated.area, fps=FPS, metadata=pressure, name="stated")
    options = dict(
        restarts=1, swarm=Swarm(size=8, iterations=4, chunk=4), polish=Polish(max_steps=3)
    )
    both = vfjax.fit_recordings([quiet, stated], settle=False, progress=False, **options)
    assert "P_s" in both[0].params and "P_s" not in both[1].params
    assert float(both[1].model.params()["P_s"]) == float(truth.params()["P_s"])
    for rec, batched in zip((quiet, stated), both):
        alone = vfjax.fit_recording(rec, settle=False, progress=False, **options)
        assert batched.nmse == pytest.approx(alone.nmse, rel=1e-9)
        assert batched.params == pytest.approx(alone.params, rel=1e-9)


#: The swarm and key of `_three_in_a_batch` (a small swarm: the batch's programs compile fast).
_BATCH_SWARM, _BATCH_KEY = Swarm(size=12, iterations=10), 3


def _three_in_a_batch():
    """One batch of three recordings of N1 (other lengths and frame rates, K 0.9 and 1.1 of
    the truth for the second and third) fitted from `_start` with `_BATCH_SWARM` and
    `_BATCH_KEY`."""
    truth = vfjax.preset("N1")
    recs = [_recording(truth, t_start=0.0301, noise_px=1.0, name="a")]
    for fps, n, f in ((3000.0, 150, 0.9), (5000.0, 240, 1.1)):
        sim = vfjax.simulate(truth.set(K=f * float(truth.params()["K"])), fps, n, t_start=0.03)
        recs.append(Recording(area=np.clip(np.asarray(sim.area), 0, None), fps=fps, name=str(n)))
    key = jax.random.key(_BATCH_KEY)
    return recs, fit_many(_start(truth), recs, swarm=_BATCH_SWARM, key=key, progress=False)


def _numbers(results) -> list:
    """Each fit's NMSE, time shift, parameters and swarm trace, as plain floats."""
    return [[r.nmse, r.time_shift, *r.params.values(), *r.pso_trace] for r in results]


#: The tests of `three_in_a_batch` run on one worker, which computes the fixture once.
_WITH_THREE_IN_A_BATCH = pytest.mark.xdist_group("three_in_a_batch")


@pytest.fixture(scope="module")
def three_in_a_batch():
    return _three_in_a_batch()


@_WITH_THREE_IN_A_BATCH
def test_a_fit_in_a_batch_equals_the_fit_alone(three_in_a_batch):
    """Fit 0 of a batch of three recordings (other lengths, frame rates) equals the same fit
    run alone: the same key gives the same numbers, whatever the rest of the batch."""
    truth = vfjax.preset("N1")
    swarm, key = _BATCH_SWARM, jax.random.key(_BATCH_KEY)
    recs, batch = three_in_a_batch
    alone = fit_many(_start(truth), recs[:1], swarm=swarm, key=key, progress=False)[0]
    # alone, padded with skipped fits to the batch's size (its programs)
    (padded,) = fit_many(_start(truth), recs[:1], swarm=swarm, key=key, min_batch=3)
    assert padded.nmse == pytest.approx(alone.nmse, rel=1e-9)
    assert padded.params == pytest.approx(alone.params, rel=1e-9)
    assert batch[0].pso_trace == pytest.approx(alone.pso_trace, rel=1e-9)
    assert batch[0].nmse == pytest.approx(alone.nmse, rel=1e-9)
    for name, value in alone.params.items():
        assert batch[0].params[name] == pytest.approx(value, rel=1e-9), name
    assert batch[0].time_shift == pytest.approx(alone.time_shift, rel=1e-9)
    for rec, r in zip(recs, batch):  # each reported NMSE is that of its fitted GAW
        assert r.nmse == pytest.approx(float(vfjax.nmse(rec.area, r.fitted_gaw())), rel=1e-9)


@_WITH_THREE_IN_A_BATCH
def test_a_contest_polishes_the_best_swarms_of_each_group_as_they_are_polished_alone(
    three_in_a_batch,
):
    """Three swarms of one recording and one of another, in two groups, of which the two
    best swarms of each are polished (as a diagnosis's refit polishes the best of a job's
    starts): the polished fits are those of the swarms that ended lowest and equal the same
    fits in a batch that polishes all; the others end as their swarms ended."""
    truth = vfjax.preset("N1")
    recs = three_in_a_batch[0]
    batch = [recs[0]] * 3 + [recs[1]]
    options = dict(swarm=_BATCH_SWARM, key=jax.random.key(_BATCH_KEY), progress=False)
    every = fit_many(_start(truth), batch, **options)
    two = fit_many(_start(truth), batch, contest=([0, 0, 0, 1], 2), **options)
    swarm_best = [f.pso_trace[-1] for f in every]
    left_out = int(np.argmax(swarm_best[:3]))
    for i, (a, b) in enumerate(zip(every, two)):
        assert b.pso_trace == a.pso_trace  # the swarms do not depend on the contest
        if i == left_out:
            assert b.optimistix_result == "not run"
            assert b.nmse == swarm_best[i]
            assert b.nmse >= max(f.nmse for k, f in enumerate(two[:3]) if k != i)
        else:
            assert b.optimistix_result != "not run"
            assert b.nmse == pytest.approx(a.nmse, rel=1e-9)
            assert b.params == pytest.approx(a.params, rel=1e-9)
            assert b.nmse < swarm_best[i]  # the polish gained
    for wrong in (([0, 1], 2), ([0, 0, 0, 1], 1.5), ([0, 0, 0, 1], True), ([0, 0, 0, 1], 0)):
        with pytest.raises(ValueError, match="contest"):
            fit_many(_start(truth), batch, contest=wrong, **options)


_ON_TWO_DEVICES = """
import collections, json, logging, re, sys
import jax
jax.config.update("jax_num_cpu_devices", 2)
jax.config.update("jax_log_compiles", True)
compiled = collections.Counter()
class Count(logging.Handler):
    def emit(self, record):
        text = record.getMessage()
        found = re.match(r"Finished XLA compilation of jit\\((\\w+?)(_stored)?\\)", text)
        if found:
            compiled[found.group(1)] += 1
logging.getLogger("jax").addHandler(Count())
sys.path.insert(0, {tests!r})
import test_fit
assert len(jax.devices()) == 2
numbers = test_fit._numbers(test_fit._three_in_a_batch()[1])
print(json.dumps([numbers, compiled]))
"""


@_WITH_THREE_IN_A_BATCH
def test_a_batch_split_over_two_devices_equals_it_on_one(three_in_a_batch):
    """The batch of three (four fits with its padding) in a process of two CPU devices, as
    the command line runs: two groups of two fits side by side, each through the same
    compiled programs, and every number equals the batch's on one device to the last bit
    (the same one-device programs for either group; a program split over the devices by
    XLA, `jax.shard_map`, rounds otherwise). The swarm's chunk and the polish compile once
    each, not once per device."""
    import subprocess
    import sys

    here = str(pathlib.Path(__file__).parent)
    run = subprocess.run(
        [sys.executable, "-c", _ON_TWO_DEVICES.format(tests=here)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert run.returncode == 0, run.stderr[-2000:]
    on_two, compiled = json.loads(run.stdout.strip().splitlines()[-1])
    assert on_two == _numbers(three_in_a_batch[1])
    assert compiled["_swarm_chunk"] == 1 and compiled["_polish_batch"] == 1, compiled


def test_a_first_fit_that_matches_the_start_up_is_made_again_after_a_longer_warm_up(
    shared_dir,
):
    """The shared syn_tremor (an independent implementation's N1-like glottis whose pressure
    modulation switches closure on and off) fitted after the default 20 ms warm-up matches
    the recording with the model's start-up from rest: `settling` finds that fit's model
    leaves more error 0.2 s later. `fit_recording` then fits it again after 0.2 s, and
    that fit's error hardly moves at 0.4 s, an independent, longer simulation. Batched
    (`fit_recordings`, beside the settled syn_gap), each recording's fit is its fit alone."""
    folder = shared_dir / "data" / "synthetic"
    tremor, gap = (load_recording(folder / f"{n}.csv") for n in ("syn_tremor", "syn_gap"))
    options = {"restarts": 1, "swarm": Swarm(iterations=30), "key": jax.random.key(0)}
    transient = vfjax.fit_recording(tremor, settle=False, **options)
    assert transient.sampling.warmup == vfjax.default_warmup(transient.model)
    start_up = vfjax.settling(transient, tremor)
    assert not start_up.settled, start_up.words()
    first = vfjax.fit_recording(tremor, **options)
    assert first.sampling.warmup == vfjax.SETTLING_WARMUP
    later = vfjax.settling(first, tremor)
    assert later.warmup == pytest.approx(2 * vfjax.SETTLING_WARMUP)
    # its error moves 0.2 s later by under a twentieth of what the start-up's did (keys 0, 1:
    # -4.7e-5 and 1.06e-4 against 9.0e-3 and 8.5e-3; about the noise floor, 7.8e-5, which it
    # exceeds with key 1: a periodic model drifts against a modulated recording that it
    # misfits by 18 %)
    assert later.nmse - later.fit_nmse < 0.05 * (start_up.nmse - start_up.fit_nmse), later
    assert first.status == "successful" and first.nmse < 0.25
    both = vfjax.fit_recordings([gap, tremor], **options)
    assert both[0].sampling.warmup == vfjax.default_warmup(both[0].model)
    assert vfjax.settling(both[0], gap).settled
    assert both[1].sampling.warmup == vfjax.SETTLING_WARMUP
    assert both[1].params == pytest.approx(first.params, rel=1e-6)


#: The tests of `continued` run on one worker, which computes the fixture once.
_WITH_CONTINUED = pytest.mark.xdist_group("continued")


@pytest.fixture(scope="module")
def continued():
    """A recording of about 31 cycles (N3, 0.15 s at 2 kHz, closure jitter) and a short one
    (101 frames), fitted in one batch: (long, short, both fits, swarm, key)."""
    long = vfjax.datasets.demo_recording("N3", 1.5, 3, 2000.0, 301, jitter=0.003)
    short = vfjax.datasets.demo_recording("N3", 1.5, 4, 2000.0, 101)
    swarm, key = Swarm(size=16, iterations=40), jax.random.key(0)
    both = vfjax.fit_recordings([long, short], restarts=1, swarm=swarm, key=key)
    return long, short, both, swarm, key


@_WITH_CONTINUED
def test_a_long_recording_is_fitted_by_continuation_in_its_length(continued):
    """The long recording: the swarm and a first polish fit its first 16 cycles, the next
    polish all of them; the fit reaches the error of the true parameters polished (a
    relative f0 error of 3 % would slip a whole cycle; a closure hold one cycle longer skips
    every other closure). The short one is polished once, from its swarm's best."""
    from vfjax._fit._engine import _stages

    long, short, both, _, _ = continued
    clean = vfjax.datasets.demo_recording("N3", 0.0, 3, 2000.0, 301, jitter=0.003)
    period = 1.0 / vfjax.descriptors.fundamental_frequency(long.area, long.fps)
    stages = _stages([long, short], [(None, period)] * 2)
    assert len(stages) == 2 and stages[-1] == [301, 101] and stages[0][1] == 101
    assert stages[0][0] == pytest.approx(16 * period * 2000.0, abs=1)
    truth = vfjax.fit(
        vfjax.preset("N3"), long, params=("S", "K", "C_f", "t_c"), swarm=Swarm(iterations=0)
    )
    floor = np.sum((long.area - clean.area) ** 2) / np.sum(long.area**2)
    assert truth.nmse < 4.0 * floor  # rounding to whole pixels and the closure jitter
    assert both[0].nmse < 1.02 * truth.nmse, (both[0].nmse, truth.nmse)
    assert both[0].params["K"] == pytest.approx(float(vfjax.preset("N3").params()["K"]), rel=0.05)


@_WITH_CONTINUED
def test_a_contests_unpolished_fits_of_a_long_recording_report_its_whole_error(continued):
    """Swarms of a recording fitted by continuation search its first 16 cycles; those a
    contest leaves unpolished report their point's NMSE on the whole recording (as its
    fitted GAW, simulated afresh, gives), not their first window's, which can be far lower
    and would win a ranking of the group's fits."""
    from vfjax._fit._engine import fit_many

    long, _, both, swarm, _ = continued
    starts = [both[0].model.set(K=both[0].params["K"] * f) for f in (0.8, 1.25)]
    fits = fit_many(
        starts,
        [long] * 2,
        tuple(both[0].params),  # a batch of two as the fixture's: its programs
        swarm=dataclasses.replace(swarm, iterations=6),
        contest=([0, 0], 1),
        progress=False,
    )
    assert [f.optimistix_result == "not run" for f in fits].count(True) == 1
    for f in fits:
        whole = float(vfjax.nmse(long.area, f.fitted_gaw(long)))
        assert f.nmse == pytest.approx(whole, rel=1e-9), (f.optimistix_result, f.nmse, whole)


@pytest.mark.slow  # a fit's independence of its batch is checked by default in a short batch
@_WITH_CONTINUED
def test_each_fit_of_a_continued_batch_equals_its_fit_alone(continued):
    """In one batch with a short recording, each fit equals its fit alone."""
    long, short, both, swarm, key = continued
    # the long recording runs through the same programs alone; the short one, alone in the
    # 128-frame bucket, in the batch's 512: the swarm's costs then round otherwise (1e-16),
    # and its polish ends 1e-7 away along a flat valley of the error, at the same NMSE
    for rec, fitted, rel in zip((long, short), both, (1e-9, 1e-6)):
        alone = vfjax.fit_recording(rec, restarts=1, swarm=swarm, key=key)
        assert fitted.nmse == pytest.approx(alone.nmse, rel=1e-9)
        assert fitted.params == pytest.approx(alone.params, rel=rel)


@_WITH_CONTINUED
def test_a_long_fit_beside_one_of_more_stages_is_its_fit_alone(continued):
    """Beside a recording of about 75 cycles (three stages: 16, 64, all), the 31-cycle
    recording's fit (two stages) is its fit beside the short one: once its own windows have
    ended it is not polished again."""
    long, _, both, swarm, key = continued
    n3 = vfjax.preset("N3")
    faster = n3.set(K=2.0 * float(n3.params()["K"]))  # f0 about 290 Hz
    mate = vfjax.datasets.demo_recording("N3", 1.5, 5, 2000.0, 510, jitter=0.003, model=faster)
    f0 = vfjax.descriptors.fundamental_frequency(mate.area, mate.fps)
    assert mate.n_frames / mate.fps * f0 > 64
    batch = vfjax.fit_recordings([long, mate], restarts=1, swarm=swarm, key=key)
    assert batch[0].nmse == pytest.approx(both[0].nmse, rel=1e-9)
    assert batch[0].params == pytest.approx(both[0].params, rel=1e-9)


def test_a_recording_is_fitted_on_its_own_windows_in_any_batch():
    """The frames of each stage: a recording's windows (16, then 64 cycles, rounded up to
    whole frames) are the same beside a recording of more stages as alone, whole once they
    have ended, and a short recording is whole at every stage. (That a recording is not
    polished at the stages after its own is the test above.)"""
    from vfjax._fit._engine import _stages

    def rec(n):
        return Recording(area=1.0 + np.sin(np.arange(n) * 2.0), fps=2000.0)

    period = 1.0 / 207.0  # s: 9.66 frames a cycle at 2 kHz
    long, longer, short = rec(301), rec(1001), rec(101)  # 31.2, 103.6 and 10.5 cycles
    sixteen, sixty_four = 155, 619  # frames of 16 and 64 cycles, rounded up
    assert _stages([long], [(None, period)]) == [[sixteen], [301]]
    assert _stages([short], [(None, period)]) == [[101]]
    both = _stages([long, longer, short], [(None, period)] * 3)
    assert [s[1] for s in both] == [sixteen, sixty_four, 1001]
    assert [s[0] for s in both] == [sixteen, 301, 301]
    assert [s[2] for s in both] == [101, 101, 101]


def test_bad_input_is_refused():
    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.03)
    with pytest.raises(ValueError, match="cannot fit"):
        fit(truth, rec, params=("S", "eta"))
    with pytest.raises(ValueError, match="bounds for K"):
        fit(truth, rec, params=("S", "K"), bounds={"K": (1.0, 2.0)})
    with pytest.raises(ValueError, match="fewer than two glottal cycles"):
        fit(truth, Recording(area=rec.area[:20], fps=FPS))
    with pytest.raises(ValueError, match="S is fixed"):
        fit(truth, Recording(area=rec.area / 43.8, fps=FPS, unit="mm2"))
    with pytest.raises(TypeError, match="Recording"):
        fit(truth, rec.area)
    with pytest.raises(ValueError, match="negative"):
        Recording(area=-rec.area, fps=FPS)
    with pytest.raises(ValueError, match="NaN"):
        Recording(area=np.r_[rec.area[:-1], np.nan], fps=FPS)
    with pytest.raises(ValueError, match="fps"):
        Recording(area=rec.area, fps=0.0)


def test_fits_from_another_subject_find_the_right_basin():
    """From N4's values (t_c measured, K matched to the recording's f0), every seed of the
    demo recording (N3 + 2 px noise) is fitted to its noise floor: no sub-harmonic trap."""
    from vfjax.datasets import demo_recording
    from vfjax.presets import initial_model

    for seed in range(3):
        rec = demo_recording("N3", seed=seed)
        start = initial_model(rec, template="N4")
        result = fit(
            start, rec, params=("S", "K", "C_f", "t_c"), key=jax.random.key(seed), progress=False
        )
        assert result.nmse < 1e-3, (seed, result.nmse, result.params)


def test_restarts_keep_the_best_and_restart_zero_is_the_fit_alone():
    """A fit with restarts is the best of independent searches, the first of which is the
    fit without restarts (same key), and each recording of a batch keeps its own best."""
    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.0305, noise_px=1.0)
    swarm = Swarm(size=12, iterations=8)
    key = jax.random.key(4)
    alone = fit(_start(truth), rec, swarm=swarm, key=key, progress=False)
    three = fit(_start(truth), rec, swarm=swarm, key=key, restarts=3, progress=False)
    assert alone.restart_nmse == [alone.nmse]
    assert len(three.restart_nmse) == 3
    assert three.restart_nmse[0] == pytest.approx(alone.nmse, rel=1e-9)
    assert three.nmse == min(three.restart_nmse)
    assert len(set(three.restart_nmse)) == 3  # independent searches, not copies
    assert three.nmse == pytest.approx(float(vfjax.nmse(rec.area, three.fitted_gaw())), rel=1e-9)
    with pytest.raises(ValueError, match="restarts"):
        fit(_start(truth), rec, swarm=swarm, restarts=0)


def test_restarts_lost_at_the_cull_stop_and_the_rest_search_on_unchanged():
    """With ``Swarm.cull_at``, a recording's restarts whose swarms lie more than
    ``cull_factor`` times behind its best after that many iterations (as the same swarms
    stopped there tell) stop there, unpolished (None); the others search on and end exactly
    where they end without the cull; the simulations skipped are not counted."""
    from vfjax._fit._engine import _survivors

    truth = vfjax.preset("N1")
    rec = _recording(truth, t_start=0.0305, noise_px=1.0)
    kw = dict(key=jax.random.key(5), restarts=4, progress=False)
    swarm = Swarm(size=8, iterations=12, chunk=4, cull_at=4, cull_factor=1.0)
    at_cut = fit(_start(truth), rec, swarm=Swarm(size=8, iterations=4), polish=None, **kw)
    whole = fit(_start(truth), rec, swarm=Swarm(size=8, iterations=12, chunk=4), **kw)
    culled = fit(_start(truth), rec, swarm=swarm, **kw)
    kept = [i for i, v in enumerate(at_cut.restart_nmse) if v == min(at_cut.restart_nmse)]
    assert [i for i, v in enumerate(culled.restart_nmse) if v is not None] == kept
    assert len(kept) < 4
    for i in kept:
        assert culled.restart_nmse[i] == pytest.approx(whole.restart_nmse[i], rel=1e-12)
    assert culled.nmse == min(whole.restart_nmse[i] for i in kept)
    assert culled.nmse == pytest.approx(float(vfjax.nmse(rec.area, culled.fitted_gaw())), rel=1e-9)
    # each restart culled skips 8 iterations of 8 particles, and its polish
    assert culled.n_simulations < whole.n_simulations - (4 - len(kept)) * 8 * 8
    # the rule: within the factor of the recording's best; all where none is finite
    costs = np.array([1e-3, 5e-3, 2e-2, np.inf, np.inf, np.inf, np.nan, np.inf, 0.0, 0.0])
    owner = np.repeat(np.arange(2), 4)
    keep = _survivors(costs, owner, 4, 10.0)
    assert keep.tolist() == [True, True, False, False, True, True, True, True, False, False]
    assert Swarm().culls(4) and not Swarm(cull_at=0).culls(4)
    assert not Swarm(iterations=20, cull_at=20).culls(4) and not Swarm().culls(1)
    for bad in ({"cull_at": -1}, {"cull_factor": 0.5}, {"cull_factor": float("nan")}):
        with pytest.raises(ValueError, match="cull"):
            Swarm(**bad)


def test_a_first_fit_searches_the_pressure_and_the_hold_from_zero():
    """`fit_recording` fits P_s unless the sidecar states it, and searches t_c linearly from
    0 (no hold), so a fit that needs no hold is not at a bound. On a recording of N1 at
    a pressure 40 % below the preset's (2 px noise; sampled from 0.23 s, where its
    oscillation has settled: a first fit describes a sustained one), the paper's protocol
    (P_s at the preset) stays far above the noise; the first fit reaches the noise's own
    NMSE."""
    truth = vfjax.preset("N1", P_s_dyne_per_cm2=6750.0)
    rec = _recording(truth, t_start=0.2307, noise_px=2.0, name="low_pressure")
    rec = Recording(rec.area, rec.fps, metadata={"sex": "male"}, name=rec.name)
    start = vfjax.initial_model(rec)
    assert vfjax.first_fit_parameters(rec, start) == ("S", "K", "C_f", "t_c", "P_s")
    box = vfjax.first_fit_bounds(start, ("S", "K", "C_f", "t_c", "P_s"))
    assert box["t_c"][0] == 0.0 and box["P_s"] == vfjax.PRESSURE_RANGE
    noise_nmse = rec.n_frames * 2.0**2 / float(np.sum(rec.area**2))
    paper = fit(start, rec, ("S", "K", "C_f", "t_c"), progress=False)
    first = vfjax.fit_recording(rec, start, progress=False)
    assert paper.nmse > 3 * noise_nmse, paper.nmse
    assert first.nmse < 1.3 * noise_nmse, (first.nmse, noise_nmse, first.params)
    assert first.status == "successful" and first.bounds["t_c"][0] == 0.0
    assert len(first.restart_nmse) == vfjax.FIRST_FIT_RESTARTS
    # a stated pressure is the model's and is not searched
    stated = Recording(rec.area, rec.fps, metadata={"subglottal_pressure_dyne_per_cm2": 6750.0})
    assert float(vfjax.initial_model(stated).params()["P_s"]) == 6750.0
    assert "P_s" not in vfjax.first_fit_parameters(stated, vfjax.initial_model(stated))


def test_no_fit_leaves_the_plausible_pressure_range():
    """P_s stays within `PRESSURE_RANGE` (widened only by the start and the given bounds):
    a recording made at 60 000 dyne/cm² is fitted at the range's edge, flagged as at its
    bound, and reached when the bounds widen the range."""
    truth = vfjax.preset("N1", P_s_dyne_per_cm2=60000.0)
    rec = _recording(truth, t_start=0.0307)
    start = _start(truth).set(P_s=25000.0)
    params = ("S", "K", "C_f", "P_s")
    held = fit(start, rec, params, progress=False)
    assert held.params["P_s"] == pytest.approx(vfjax.PRESSURE_RANGE[1], rel=1e-12)
    assert held.bounds["P_s"] == pytest.approx([12500.0, 30000.0])  # 0.5-2x, within the range
    assert held.status == "at_bound" and held.nmse > 1e-4
    wide = fit(start, rec, params, bounds={"P_s": (1000.0, 1e5)}, progress=False)
    assert wide.params["P_s"] == pytest.approx(60000.0, rel=0.02)
    assert wide.nmse < 1e-5


@_WITH_N1_FIT
def test_settling_tells_a_sustained_oscillation_from_the_start_up(n1_fit):
    """`settling`: N1 closes every cycle (the hold resets its state), so after 0.2 s its fit
    leaves the same error; without flow separation its oscillation decays and never closes
    (MODEL_SPEC), so a fit of its first 50 ms matches a transient that 0.2 s later is gone."""
    _, rec, result = n1_fit
    noisy = Recording(
        np.clip(rec.area + np.random.default_rng(1).normal(0, 2.0, rec.n_frames), 0, None),
        rec.fps,
        name="n1_noisy",
    )
    seen = _compilations()
    sustained = vfjax.settling(result, noisy)
    assert sustained.settled and sustained.warmup == vfjax.SETTLING_WARMUP
    # its S and shift polished by the fit's own compiled polish: the one program of its own
    # is the grid of shifts after the longer warm-up (and the fitted GAW's simulation)
    programs = {re.sub(r"^jit\((.*)\)$", r"\1", n).removesuffix("_stored") for n in seen}
    assert programs <= {"start_point", "simulate_frames", "stack", "convert_element_type"}, seen
    # S and the shift found afresh on the noisy recording: at most the fit's own error
    unchanged = float(vfjax.nmse(noisy.area, result.fitted_gaw()))
    assert 0.98 * unchanged <= sustained.fit_nmse <= unchanged
    assert sustained.nmse == pytest.approx(sustained.fit_nmse, rel=0.05)
    # the fit is the truth, so its residual is the noise alone (clipped where closed)
    assert sustained.noise_nmse == pytest.approx(unchanged, rel=0.3)
    decaying = vfjax.preset("N1").without(vfjax.terms.paper.FlowSeparation)
    start_up = _recording(decaying, t_start=0.0213, name="no_flow_separation")
    # S alone, from the truth: four particles evaluated once, no swarm iterations, and the
    # polish finds S
    at_truth = vfjax.Swarm(size=4, iterations=0)
    fitted = fit(decaying, start_up, ("S",), swarm=at_truth, progress=False)
    transient = vfjax.settling(fitted, start_up)
    assert fitted.nmse < 1e-4 and not transient.settled
    assert transient.nmse > 100 * fitted.nmse
    assert "not settled" in transient.words() and "warmup=0.2" in transient.words()
    with pytest.raises(ValueError, match="longer than the fit's"):
        vfjax.settling(fitted, start_up, warmup_s=0.01)
    # `fit_recordings` checks its fits in one batch, dealt to the devices: each recording's
    # check the same, bit for bit, as alone (two recordings of one length; each pair of
    # problems polished through the program of a check alone)
    assert settlings([result, fitted], [noisy, start_up]) == [sustained, transient]
    # a first fit that is not settled gives way to its fit after SETTLING_WARMUP, unless
    # that one's search failed: a model that does not describe the waveform there says less
    # than the unsettled fit, which then stays, with its settling's warning
    for status in ("successful", "at_bound", "worse_than_mean", "not_finite"):
        again = dataclasses.replace(result, status=status)
        kept = _settled_or_first(fitted, again)
        assert kept is (fitted if status in ("worse_than_mean", "not_finite") else again)
    # a slow camera: at 2 000 fps N3's open phase holds too few runs of five open frames for
    # the residual to show its 2 px noise; the fit's own error then bounds the noise's, so
    # the rounding of two realignments is not read as a start-up
    # (the sampling and swarm of test_simulate's slow camera: the same compiled fit)
    slow = vfjax.datasets.demo_recording("N3", fps=2000.0, n_frames=201, seed=3)
    fitted = fit(vfjax.preset("N3"), slow, ("S",), swarm=at_truth, progress=False)
    assert vfjax.descriptors.noise_level(slow.area, fitted.fitted_gaw()) == 0.0
    closing = vfjax.settling(fitted, slow)
    assert closing.noise_nmse == closing.fit_nmse and closing.settled, closing
    assert closing.nmse == pytest.approx(closing.fit_nmse, rel=0.05)


def test_one_recording_fits_refuse_the_batch_options():
    """`fit` and `fit_recording` fit one recording: `fit_many`'s ``hold``, ``min_batch`` and
    ``contest`` are refused by name, before anything is fitted."""
    rec = _recording(vfjax.preset("N1"), t_start=0.03)
    for one, args in ((fit, (vfjax.preset("N1"), rec)), (vfjax.fit_recording, (rec,))):
        for name in ("hold", "min_batch", "contest"):
            with pytest.raises(TypeError, match=f"takes no '{name}'"):
                one(*args, **{name: 2})
