"""The integrator against analytic solutions, and its flags, phases and batching."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vfjax
from vfjax import ClosureHold, Elastic, Subject, TanhDamping, VocalFoldModel, phases

FPS = 4000.0


def _oscillator(K=3.0e5, C_min=0.0, mass=0.1):
    """Spring (and constant damper) only: no flow, no hold. Events still fire, harmlessly."""
    terms = (Elastic(K=K), TanhDamping(C_f=0.0, C_min=C_min))
    return VocalFoldModel(Subject(mass=mass), terms, S=1.0)


def test_undamped_oscillator_matches_cosine():
    m = _oscillator()
    x_init = 0.02
    # RK4's global error here is ~ T w (w h)^4 / 120: 4e-7 relative at 16 steps a frame.
    sim = vfjax.simulate(m, FPS, 201, initial_displacement=x_init, substeps=64)
    w = np.sqrt(3.0e5 / 0.1)
    exact = x_init * np.cos(w * np.asarray(sim.time))
    assert np.max(np.abs(np.asarray(sim.displacement) - exact)) < 1e-10
    assert (
        np.max(np.abs(np.asarray(sim.velocity) + x_init * w * np.sin(w * np.asarray(sim.time))))
        < 1e-5
    )
    assert int(sim.n_events) > 10  # the folds crossed x_0 and x_c many times on the way


def test_damped_oscillator_matches_analytic_solution():
    K, C, M, x_init = 3.0e5, 40.0, 0.1, 0.02
    sim = vfjax.simulate(_oscillator(K, C, M), FPS, 201, initial_displacement=x_init, substeps=64)
    t = np.asarray(sim.time)
    zeta_w = C / (2 * M)
    wd = np.sqrt(K / M - zeta_w**2)
    exact = x_init * np.exp(-zeta_w * t) * (np.cos(wd * t) + zeta_w / wd * np.sin(wd * t))
    assert np.max(np.abs(np.asarray(sim.displacement) - exact)) < 1e-10


def test_closure_hold_lasts_exactly_t_c():
    m = vfjax.preset("N3")
    sim = vfjax.simulate(m, FPS, 201)
    d = sim.dense
    t, x, v = (np.asarray(a) for a in (d.t, d.x, d.v))
    x0 = float(m.contact_displacement)
    # hold segments: consecutive nodes with the same x <= x_0, v == 0, and time advancing
    holds, start = [], None
    for i in range(len(t) - 1):
        resting = x[i] <= x0 and v[i] == 0 and x[i + 1] == x[i] and v[i + 1] == 0
        resting = resting and (t[i + 1] > t[i] or start is not None)
        if resting and start is None:
            start = t[i]
        if not resting and start is not None:
            holds.append(t[i] - start)
            start = None
    assert len(holds) >= 8
    np.testing.assert_allclose(holds, 2.75e-3, rtol=0, atol=1e-12)


def test_phases_follow_their_definition():
    m = vfjax.preset("N1")
    sim = vfjax.simulate(m, FPS, 201)
    x, v, ph = (np.asarray(a) for a in (sim.displacement, sim.velocity, sim.phase))
    x0, xc = float(m.contact_displacement), float(m.subcritical_displacement())
    eps = 1e-9
    assert np.all(ph[x > xc + eps] == phases.OPEN)
    assert np.all(ph[x < x0 - eps] == phases.CLOSED)
    inner = (x < xc - eps) & (x > x0 + eps)
    assert np.all(ph[inner & (v < -eps)] == phases.CLOSING)
    assert np.all(ph[inner & (v > eps)] == phases.OPENING)
    assert set(np.unique(ph)) == {0, 1, 2, 3}
    # closed frames have (numerically) zero or negative area
    assert np.all(np.asarray(sim.glottal_area)[ph == phases.CLOSED] <= 1e-9)


def test_vmap_over_parameters_equals_a_loop():
    m = vfjax.preset("N1")
    Ks = jnp.array([0.9, 1.0, 1.1]) * m.params()["K"]
    batched = jax.vmap(lambda k: vfjax.simulate(m.set(K=k), FPS, 101).area)(Ks)
    for k, row in zip(Ks, batched):
        single = vfjax.simulate(m.set(K=k), FPS, 101).area
        np.testing.assert_allclose(row, single, rtol=0, atol=1e-9)


def test_loop_carries_start_batched_with_the_same_values():
    """`batched_like` (the initial carries of the integrator's loops and of the
    Levenberg-Marquardt scan, batched from their first trace): the values unchanged whatever
    the probe holds (NaN and inf included) and in every dtype; under vmap batched wherever
    the probe is (vmap refuses ``out_axes=None`` for a batched output); its derivative zero,
    never NaN."""
    from vfjax._batching import batched_like

    tree = (jnp.zeros(3), jnp.ones((), jnp.float32), jnp.int32(7), jnp.array(True), jnp.inf)
    for probe in (1.5, jnp.nan, -jnp.inf, {"model": jnp.arange(3.0), "name": "N1"}):
        for got, leaf in zip(batched_like(probe, tree), tree):
            assert got.dtype == jnp.asarray(leaf).dtype
            np.testing.assert_array_equal(got, leaf)
    probes = jnp.array([1.0, jnp.nan, 2.0])
    jax.vmap(lambda p: jnp.zeros(3), out_axes=None)(probes)  # a constant stays unbatched
    batched = jax.vmap(lambda p: batched_like(p, tree))(probes)
    for got, leaf in zip(batched, tree):
        np.testing.assert_array_equal(got, jnp.broadcast_to(leaf, (3,) + jnp.shape(leaf)))
    for leaf in tree:
        with pytest.raises(ValueError, match="out_axes"):
            jax.vmap(lambda p, leaf=leaf: batched_like(p, leaf), out_axes=None)(probes)
    for p in (1.5, jnp.nan, jnp.inf):
        assert float(jax.grad(lambda p: batched_like(p, 2.0))(p)) == 0.0
        _, tangent = jax.jvp(lambda p: batched_like(p, 2.0), (p,), (1.0,))
        assert float(tangent) == 0.0


def test_divergence_is_flagged_not_crashed():
    # A 1 µg fold with N1's stiffness: omega * dt ~ 10, RK4 is unstable and the state blows up.
    m = vfjax.preset("N1").set(M=1e-6).without(ClosureHold)
    sim = jax.jit(lambda m: vfjax.simulate(m, FPS, 101, throw=False))(m)
    assert bool(sim.diverged) and not bool(sim.complete)
    assert bool(sim.result == vfjax.RESULTS.diverged)
    area = np.asarray(sim.area)
    assert np.isnan(area[-1])  # nothing after the divergence is passed off as a result
    assert np.all(np.isfinite(area[: np.argmax(np.isnan(area))]))
    # and a healthy model is not flagged
    ok = vfjax.simulate(vfjax.preset("N1"), FPS, 101)
    assert not bool(ok.diverged) and bool(ok.complete)
    assert bool(ok.result == vfjax.RESULTS.successful)
    # throw=True (the default) raises, outside jit and inside it
    with pytest.raises(vfjax.SimulationError, match="physical range"):
        vfjax.simulate(m, FPS, 101)
    with pytest.raises(Exception, match="physical range"):
        jax.jit(lambda m: vfjax.simulate(m, FPS, 101).area)(m).block_until_ready()


def test_event_budget_exhaustion_is_reported():
    # without the hold every grid step and every switch takes an iteration: 3 do not suffice
    m = vfjax.preset("N1").without(ClosureHold)
    sim = vfjax.simulate(m, FPS, 201, max_events=3, throw=False)
    assert not bool(sim.complete) and not bool(sim.diverged)
    assert bool(sim.result == vfjax.RESULTS.event_budget_exhausted)
    with pytest.raises(vfjax.SimulationError, match="event budget"):
        vfjax.simulate(m, FPS, 201, max_events=3)
    assert np.isnan(np.asarray(sim.area)[-1])
    # a budget of as many switches as the run makes is enough
    n = int(vfjax.simulate(m, FPS, 201).n_events)
    assert n > 30
    enough = vfjax.simulate(m, FPS, 201, max_events=n)
    assert bool(enough.complete) and np.isfinite(np.asarray(enough.area)[-1])


def test_substeps_converge():
    m = vfjax.preset("N4")
    ref = np.asarray(vfjax.simulate(m, FPS, 201, substeps=256).area)
    errs = []
    for k in (4, 16):
        a = np.asarray(vfjax.simulate(m, FPS, 201, substeps=k).area)
        errs.append(np.sum((a - ref) ** 2) / np.sum(ref**2))
    assert errs[1] < errs[0] and errs[1] < 1e-6


@pytest.mark.parametrize("name", ["N1", "N3"])
def test_a_slow_camera_gets_steps_short_enough_by_default(name):
    """At 2 kHz, 4 RK4 steps a frame (125 us) simulate N1 and N3 without their closed phase
    (NMSE about 2 against a converged reference); the default steps a frame keep the step
    within 1/16 000 s, as at 4 kHz, and the GAW within 1e-4 of the reference."""
    m = vfjax.preset(name)
    assert vfjax.default_substeps(2000.0) == 8 and vfjax.default_substeps(3000.0) == 6
    assert vfjax.default_substeps(4000.0) == vfjax.default_substeps(5000.0) == 4
    assert vfjax.default_substeps(8000.0) == 2 and vfjax.default_substeps(20000.0) == 1
    assert vfjax.Sampling(2000.0, 201).substeps == 8
    ref = np.asarray(vfjax.simulate(m, 2000.0, 201, substeps=64, t_start=0.03).area)

    def error(area):
        return float(np.sum((np.asarray(area) - ref) ** 2) / np.sum(ref**2))

    assert error(vfjax.simulate(m, 2000.0, 201, t_start=0.03).area) < 1e-4
    assert error(vfjax.simulate(m, 2000.0, 201, substeps=4, t_start=0.03).area) > 0.5
    # a fit samples a 2 kHz recording at the same default
    rec = vfjax.Recording(area=np.clip(ref, 0.0, None), fps=2000.0)
    fitted = vfjax.fit(m, rec, params=("S",), swarm=vfjax.Swarm(size=4, iterations=0))
    assert fitted.sampling.substeps == 8 and fitted.nmse < 1e-4


def test_a_fast_camera_gets_the_same_step_by_default():
    """At 8 and 16 kHz the default takes 2 steps and 1 a frame (the step of 4 at 4 kHz,
    1/16 000 s): the GAW of N1 and N3 stays within 1e-5 of a 16 times finer reference, as at
    4 kHz."""
    for fps, frames in ((8000.0, 401), (16000.0, 801)):
        for name in ("N1", "N3"):  # the second model runs through the first one's programs
            m = vfjax.preset(name)
            ref = np.asarray(vfjax.simulate(m, fps, frames, substeps=64 * 4000 // int(fps)).area)
            area = np.asarray(vfjax.simulate(m, fps, frames).area)
            assert np.sum((area - ref) ** 2) / np.sum(ref**2) < 1e-5, (fps, name)


def test_time_shift_is_differentiable_and_moves_the_samples():
    m = vfjax.preset("N1")
    shift = 1.0e-4

    def gaw(s):
        return vfjax.simulate(m, FPS, 101, time_shift=s, max_time_shift=1e-3).area

    later = vfjax.simulate(m, FPS, 101, t_start=shift).area
    np.testing.assert_allclose(gaw(shift), later, atol=1e-6)
    _, tangent = jax.jvp(gaw, (shift,), (1.0,))
    fd = (gaw(shift + 1e-8) - gaw(shift - 1e-8)) / 2e-8
    assert float(jnp.linalg.norm(tangent - fd) / jnp.linalg.norm(fd)) < 1e-3


def test_a_hold_takes_one_iteration_and_the_loop_stops_when_done():
    # N1 is held closed for ~60 % of the run: its nodes reach the last frame in well under
    # the grid's 800 steps, and the rest of the node list repeats the final state.
    sim = vfjax.simulate(vfjax.preset("N1"), FPS, 201)
    t = np.asarray(sim.dense.t)
    n_grid = 4 * 200
    last = int(np.argmax(t >= t[-1]))
    assert last < 0.5 * n_grid
    assert t[-1] == 200 / FPS and np.all(np.asarray(sim.dense.x)[last:] == float(sim.dense.x[-1]))


def test_the_early_stopping_loop_equals_the_differentiated_scan():
    # The value comes from the loop, derivatives from a scan of the full budget (or, with
    # reverse_mode=False, from the loop): all three must agree exactly, in batches that mix
    # members that close (and stop early) with members that never close.
    base = vfjax.preset("N1")
    scales = jnp.asarray([0.8, 0.95, 1.0, 1.05, 1.2, 1.5])
    batch = jax.vmap(lambda s: base.set(K=base.params()["K"] * s, P_s=base.params()["P_s"] * s))(
        scales
    )
    closes = np.asarray(
        jax.vmap(lambda m: jnp.any(vfjax.simulate(m, FPS, 201).phase == phases.CLOSED))(batch)
    )
    assert closes.any() and not closes.all()

    def run(reverse_mode):
        def f(k):
            m = jax.vmap(lambda m, k: m.set(K=k))(batch, k)
            sims = jax.vmap(lambda m: vfjax.simulate(m, FPS, 201, reverse_mode=reverse_mode))(m)
            return sims.area, sims.dense.t

        k = batch.params()["K"]
        return f(k), jax.jvp(f, (k,), (k * 1e-3,))

    (area, t), ((area_scan, t_scan), (d_area, _)) = run(True)
    _, ((area_loop, t_loop), (d_area_loop, _)) = run(False)
    for a, b in ((area, area_scan), (area, area_loop), (t, t_scan), (t, t_loop)):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    np.testing.assert_array_equal(np.asarray(d_area), np.asarray(d_area_loop))
    assert np.all(np.isfinite(np.asarray(d_area))) and np.any(np.asarray(d_area) != 0)


def test_a_sampling_object_samples_as_its_fields():
    """`simulate(model, Sampling)` samples as the frame rate, frames, substeps, warm-up (as
    t_start) and shift range it holds; mixing the two forms is refused."""
    m = vfjax.preset("N1")
    s = vfjax.Sampling(fps=5000.0, n_frames=120, substeps=5, warmup=0.02, max_time_shift=0.004)
    a = vfjax.simulate(m, s, time_shift=0.001)
    b = vfjax.simulate(
        m, 5000.0, 120, substeps=5, t_start=0.02, max_time_shift=0.004, time_shift=0.001
    )
    np.testing.assert_array_equal(np.asarray(a.area), np.asarray(b.area))
    assert a.area.shape == (120,) and float(np.max(a.area)) > 100.0
    with pytest.raises(TypeError, match="n_frames given with a Sampling"):
        vfjax.simulate(m, s, 120)
    with pytest.raises(TypeError, match="give n_frames"):
        vfjax.simulate(m, 5000.0)


def test_a_demo_recording_starts_at_its_warmup():
    """`demo_recording(warmup=w)` samples the model from w seconds after the onset: without
    noise its GAW is the simulation from t_start = w, rounded to whole pixels; the default
    starts 7.7 ms after the model's default warm-up; a negative warm-up is refused."""
    from vfjax.datasets import demo_recording

    model = vfjax.preset("N1")
    for warmup, t_start in ((None, vfjax.default_warmup(model) + 0.0077), (0.3, 0.3)):
        rec = demo_recording("N1", noise_px=0.0, n_frames=120, warmup=warmup)
        sim = np.asarray(vfjax.simulate(model, 4000.0, 120, t_start=t_start).area)
        np.testing.assert_array_equal(rec.area, np.clip(np.round(sim), 0.0, None))
    with pytest.raises(ValueError, match="warmup"):
        demo_recording("N1", warmup=-0.1)


def _scaled_n1(term):
    """Six N1 models, K and P_s scaled together from 0.8 to 1.5 (some close, some never do),
    with a source-tract inertance (a term with an internal state) for ``term`` "tract"."""
    base = vfjax.preset("N1")
    if term == "tract":
        base = base.with_term(vfjax.SourceTractInertance(I_t=0.0074))
    scales = jnp.asarray([0.8, 0.95, 1.0, 1.05, 1.2, 1.5])
    return jax.vmap(lambda s: base.set(K=base.params()["K"] * s, P_s=base.params()["P_s"] * s))(
        scales
    )


@pytest.mark.parametrize("term", [None, "tract"])
def test_the_swarms_single_precision_window_follows_the_double_one(term):
    """The swarm's profile integrates in single precision (`integrate_window_single`): its
    frames stay within single precision's rounding of the double-precision ones (NMSE below
    1e-9, far under any recording's noise) for members that close and members that never
    close, and for a term with an internal state (the source-tract inertance); the output
    comes back in double precision."""
    from vfjax._integrate import (
        integrate_window,
        integrate_window_single,
        sample_window,
        sampled_grid,
        window_size,
    )

    batch = _scaled_n1(term)
    sampling = vfjax.Sampling(fps=FPS, n_frames=201, substeps=4, warmup=0.02, max_time_shift=0.0)
    grid = sampled_grid(sampling)
    n_out, n_rows = window_size(sampling)

    @jax.jit
    @jax.vmap
    def frames(model):
        double = integrate_window(model, grid, n_rows=n_rows)
        single = integrate_window_single(model, grid, n_rows=n_rows)
        sample = lambda i: sample_window(model, grid, 0.0, i, n_out=n_out)  # noqa: E731
        return sample(double), sample(single)

    double, single = frames(batch)
    assert single.area.dtype == jnp.float64
    a, b = np.asarray(double.area), np.asarray(single.area)
    closes = np.asarray(jnp.any(double.phase == phases.CLOSED, axis=1))
    assert closes.any() and (term is not None or not closes.all())
    np.testing.assert_array_equal(closes, np.asarray(jnp.any(single.phase == phases.CLOSED, 1)))
    nmse = np.sum((a - b) ** 2, axis=1) / np.sum(a**2, axis=1)
    assert np.all(nmse < 1e-9), nmse
    assert np.all(nmse > 0)  # it is single precision: not the double-precision bits


def _in_both_layouts(batch, grid, n_rows):
    """`integrate_window` of the vmapped ``batch`` (a `SampledGrid` shared, or one a member)
    in the chunked loop and in the small-batch layout: their two ``(begin, end, rows)``."""
    from vfjax._integrate import integrate_window

    shared = jnp.ndim(grid.h) == 0

    def integrate(small):
        def one(m, g):
            return integrate_window(m, g, n_rows=n_rows, small_batch=small)

        return jax.jit(jax.vmap(one, in_axes=(0, None if shared else 0)))(batch, grid)

    return integrate(False), integrate(True)


@pytest.mark.parametrize("term", [None, "tract"])
def test_a_small_batch_integrates_the_same_motion_step_by_step(term):
    """`integrate_window(small_batch=True)` (the swarm's layout: each iteration a program of
    its own, its row written by the loop around it) integrates the motion of the chunked loop:
    in double precision, the same nodes and phases, times and states within 1e-12 of them
    (XLA compiles the iteration's arithmetic otherwise there, so not the same bits), for
    members that close and members that never close, with and without a term's internal
    state, and the same state where the kept rows begin and at the end."""
    from vfjax._integrate import sampled_grid, window_size

    batch = _scaled_n1(term)
    sampling = vfjax.Sampling(fps=FPS, n_frames=201, substeps=4, warmup=0.02)
    grid = sampled_grid(sampling)
    _, n_rows = window_size(sampling)

    (begin, end, rows), (begin_s, end_s, rows_s) = _in_both_layouts(batch, grid, n_rows)
    t, x, v, code, z = rows
    t_s, x_s, v_s, code_s, z_s = rows_s
    np.testing.assert_array_equal(np.asarray(code), np.asarray(code_s))
    closes = np.any(np.asarray(code) == phases.CLOSED, axis=1)
    assert closes.any() and (term is not None or not closes.all())
    np.testing.assert_allclose(np.asarray(t_s), np.asarray(t), rtol=1e-12, atol=0)
    scale = float(np.max(np.abs(np.asarray(x))))
    np.testing.assert_allclose(np.asarray(x_s), np.asarray(x), rtol=0, atol=1e-12 * scale)
    speed = float(np.max(np.abs(np.asarray(v))))
    np.testing.assert_allclose(np.asarray(v_s), np.asarray(v), rtol=0, atol=1e-10 * speed)
    assert jax.tree.structure(z) == jax.tree.structure(z_s) and len(jax.tree.leaves(z)) == (
        0 if term is None else 1
    )
    for a, b in zip(jax.tree.leaves(z), jax.tree.leaves(z_s)):
        size = float(np.max(np.abs(np.asarray(a))))
        np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=0, atol=1e-10 * size)
    for a, b in ((begin, begin_s), (end, end_s)):
        np.testing.assert_array_equal(np.asarray(a.step), np.asarray(b.step))
        np.testing.assert_array_equal(np.asarray(a.flags), np.asarray(b.flags))
        np.testing.assert_array_equal(np.asarray(a.events), np.asarray(b.events))
        np.testing.assert_allclose(np.asarray(b.t), np.asarray(a.t), rtol=1e-12, atol=0)


def test_a_member_beyond_its_warm_up_budget_stops_there_in_either_layout():
    """A member whose warm-up runs out of its iteration budget (`SampledGrid.warm_budget`,
    data per member: a batch of fits of several recordings) stays where it stopped, in the
    swarm's small-batch layout as in the chunked loop, whatever its batch-mates' budgets: its
    kept rows begin there (before the window: not warmed), and a particle's cost cannot depend
    on the batch it ran in."""
    from vfjax._integrate import sampled_grid, window_size

    batch = _scaled_n1(None)
    n = jax.tree.leaves(batch)[0].shape[0]
    sampling = vfjax.Sampling(fps=FPS, n_frames=201, substeps=4, warmup=0.02)
    grid = sampled_grid(sampling)
    _, n_rows = window_size(sampling)
    short = np.arange(n) % 2 == 0  # 40 iterations (48 in whole trips) of the 288 steps
    budgets = jnp.where(short, 40, grid.warm_budget)
    grids = jax.vmap(lambda b: eqx.tree_at(lambda g: g.warm_budget, grid, b))(budgets)
    (begin, end, rows), (begin_s, end_s, rows_s) = _in_both_layouts(batch, grids, n_rows)
    window = int(grid.window_step)
    steps = np.asarray(begin.step)
    assert np.all(steps[short] < window) and np.all(steps[~short] == window), steps
    for a, b in ((begin, begin_s), (end, end_s)):
        np.testing.assert_array_equal(np.asarray(b.step), np.asarray(a.step))
        np.testing.assert_array_equal(np.asarray(b.events), np.asarray(a.events))
        np.testing.assert_allclose(np.asarray(b.t), np.asarray(a.t), rtol=1e-12, atol=0)
    np.testing.assert_array_equal(np.asarray(rows_s[3]), np.asarray(rows[3]))  # phases
    np.testing.assert_allclose(np.asarray(rows_s[0]), np.asarray(rows[0]), rtol=1e-12, atol=0)


def test_roots_solved_apart_are_the_stacked_roots_and_solve_the_cubic():
    """`hermite_roots` of problems given apart, its Newton iterations looped or unrolled,
    equals `hermite_root` of the same problems stacked, and each root solves its cubic:
    against a bisection to machine precision (in numpy) for random cubics with a sign change
    over the step, a step starting on the surface (its trivial root at 0 divided out) and a
    step starting at rest."""
    from vfjax._hermite import hermite, hermite_root, hermite_roots

    rng = np.random.default_rng(3)
    n = 64
    y0, y1 = rng.uniform(-1, 1, n), rng.uniform(-1, 1, n)
    d0, d1 = rng.uniform(-2, 2, n), rng.uniform(-2, 2, n)
    target = np.where(rng.uniform(size=n) < 0.5, np.minimum(y0, y1), np.maximum(y0, y1))
    target = target + (0.5 - rng.uniform(size=n)) * np.abs(y1 - y0)  # between y0 and y1
    target[:4] = y0[:4]  # on the surface at theta = 0: its return crossing
    d0[:4] = np.where(y1[:4] > y0[:4], -1.5, 1.5)  # leaves the surface, comes back
    d0[4:8] = 0.0  # at rest
    first = (y0, d0, y1, d1, target)
    second = tuple(np.roll(a, 7) for a in first)
    apart = hermite_roots(first, second)
    unrolled = jax.jit(lambda a, b: hermite_roots(a, b, unrolled=True))(first, second)
    stacked = hermite_root(*(jnp.stack([a, b]) for a, b in zip(first, second)))
    for root, other, row in zip(apart, unrolled, stacked):
        np.testing.assert_allclose(np.asarray(root), np.asarray(row), rtol=1e-14, atol=1e-15)
        np.testing.assert_allclose(np.asarray(other), np.asarray(row), rtol=1e-14, atol=1e-15)

    def bisect(y0, d0, y1, d1, target):
        g = lambda th: np.asarray(hermite(th, y0, d0, y1, d1)) - target  # noqa: E731
        lo, hi = np.zeros(n), np.ones(n)
        # the return crossing of a step that starts on the surface: search past its start
        lo = np.where(g(lo) == 0, 1e-9, lo)
        for _ in range(80):
            mid = 0.5 * (lo + hi)
            same = np.sign(g(mid)) == np.sign(g(lo))
            lo, hi = np.where(same, mid, lo), np.where(same, hi, mid)
        return 0.5 * (lo + hi), np.sign(g(np.full(n, 1e-9))) != np.sign(g(np.ones(n)))

    for root, problem in zip(apart, (first, second)):
        truth, bracketed = bisect(*problem)
        ok = bracketed & (np.abs(np.asarray(hermite(truth, *problem[:4])) - problem[4]) < 1e-12)
        assert ok.sum() > n // 2
        np.testing.assert_allclose(np.asarray(root)[ok], truth[ok], rtol=0, atol=1e-9)
