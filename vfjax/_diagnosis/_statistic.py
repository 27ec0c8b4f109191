"""The refit statistic that a diagnosis computes alike on the recording and on its null
recordings (a parametric bootstrap of the test).

On every recording the same statistic is computed by the same compiled programs
(`_statistics`, one per group of candidates that share a warm-up, `refit_groups`): the
control refit of the fitted parameters, then each candidate's refit from the control's
optimum and from the same fixed starts (`refit_jobs`; `Calibration.steps`
Levenberg-Marquardt steps each, whose Jacobian is computed at every
`Calibration.jacobian_every`-th step and updated by secants between). A candidate's refit
never ends worse than its control: the control's optimum, with the effect off, is one of its
points. The refits' falls are standardised as F-test p-values (`f_p_values`) and compared
across candidates with a step of max-T (`family_p_values`).
"""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
from scipy import stats
from scipy.stats import qmc

from .._fit import FitResult, search_range
from .._fit._engine import group_devices, placed, side_by_side
from .._fit._polish import levenberg_marquardt
from .._fit._problem import prepare, start_point
from .._programs import program
from ..descriptors import fundamental_frequency
from ..recording import Recording
from ._candidates import Candidate, extended
from ._options import DEFAULT_CALIBRATION, Calibration


@dataclasses.dataclass(frozen=True)
class _Jobs:
    """The refits of one statistic: the control, then each candidate from its starts (host
    arrays: built, padded and cut with NumPy, placed on a device by the programs' calls)."""

    problem: object  # the group's wide model's `Problem` (the observed recording's data)
    y0: np.ndarray  # (n_y,) where every refit starts: the control's point on the recording
    starts: np.ndarray  # (jobs, n_y) candidate starts; NaN where the control's optimum is taken
    frees: np.ndarray  # (1 + jobs, n_params) fitted parameters of the control and each job
    bases: np.ndarray  # (1 + jobs, columns, n_y) each refit's search directions
    owner: tuple  # candidate index of each job (in the diagnosis's list of candidates)
    # starts chosen on each recording: a pool of points whose time shift and S are found
    # afresh there (`Problem.start`), ranked per candidate by the cost so profiled
    pool: np.ndarray  # (entries, n_y) NaN where the control's optimum is taken
    pool_free: np.ndarray  # (entries, n_params) fitted parameters of each entry
    pool_owner: np.ndarray  # (entries,) candidate index of each entry (-1: padding)
    rank: np.ndarray  # (jobs,) which of its candidate's entries a job starts from (-1: none)
    # the control's extra starts (`Calibration.control_starts`): offsets of its search
    # coordinates from y0, the first row zero
    restarts: np.ndarray  # (1 + control_starts, names) or (0, names)


def _refit(problem, y0, basis, steps: int, jacobian_every: int):
    """`levenberg_marquardt` on ``problem``'s residual, with its Jacobian
    (`Problem.residual_and_jacobian`, at every ``jacobian_every``-th step): (point, NMSE)."""
    return levenberg_marquardt(
        problem.residual, y0, basis, steps, problem.residual_and_jacobian, jacobian_every
    )


@program
def _refit_control(problem, y0, free, basis, steps: int, jacobian_every: int):
    """The control's refit on the problem's own recording: (point, NMSE)."""
    return _refit(dataclasses.replace(problem, free=free), y0, basis, steps, jacobian_every)


def settled(jobs: _Jobs, steps: int, jacobian_every: int) -> _Jobs:
    """``jobs`` starting from the control refitted on the recording in the group's own
    sampling (``2 * steps`` steps from the fit's point), for a group whose warm-up is longer
    than the fit's. There the fit's point is not the control's optimum (a longer warm-up
    changes the state at the first frame: syn_gap's fit with its gap, simulated after 0.1 s
    rather than its 20 ms, has 2.4 times its error until refitted), and refits from it
    within a few steps would differ by where they stop."""
    basis = _control_basis(jobs.bases)
    y, _ = _refit_control(
        jobs.problem, jobs.y0, jobs.frees[0], basis, 2 * int(steps), int(jacobian_every)
    )
    return dataclasses.replace(jobs, y0=np.asarray(y))


@program
def _statistics(
    problem, y0, starts, frees, bases, pool, restarts, data, steps: int, jacobian_every: int
):
    """For each recording (rows of ``data``): the control's NMSE and point, and each job's
    NMSE (never above the control's) and point. The control takes ``2 * steps`` steps (one
    refit beside the many jobs: a control left short of its optimum would hand every
    candidate a fall of its own) from ``y0`` and, where ``restarts`` has rows, from the best
    of ``y0`` moved by each row with its time shift and S found afresh
    (`Calibration.control_starts`), and the jobs without a start of their own continue
    from its optimum. (`run_statistics` splits the recordings into shares, one per device.)

    The control is then refitted again (``steps`` steps) from each candidate's best refit
    with its effect switched off (its other coordinates kept), and takes the best of those
    where it is better: a refit whose fitted parameters found a basin that the control's
    steps from the fit's point did not reach shows the control that basin. On a null
    recording whose control stopped short, every candidate would otherwise fall far (on one
    of the injection-recovery benchmark's N3 gap recordings at 3 px, seed 1, a null
    recording's control at NMSE 0.197 % beside the gap's refit at 0.062 %: refitted from
    that refit, the control reaches 0.066 %), and the family-wise test would count that
    fall against every candidate on the recording.

    ``bases`` is ``(the control's search directions, each job's)``: the control moves
    fewer coordinates than the jobs, whose directions are padded to the widest job's.

    ``pool`` is ``(entries, entries' free parameters, entries' candidates, jobs' ranks,
    jobs' candidates, candidates)``: on each recording, every entry's time shift and S are
    found afresh and its cost profiled (one simulation each), and a job with a rank
    ``r >= 0`` starts from its candidate's entry of ``r``-th lowest cost: a choice made alike
    on every recording, null or observed. ``candidates``: the candidates the jobs belong to
    (padded with -1)."""
    entries, entry_free, entry_owner, ranks, job_owner, members = pool
    n_names = len(problem.names)
    # the coordinates the control moves (its fitted parameters, the time shift and S): a
    # refit's point with the others at the fit's (the candidates' off-values) is the
    # control's
    control_basis, job_bases = bases
    kept = jnp.sum(control_basis, axis=0) > 0

    def refit(problem, y, basis, steps):
        return _refit(problem, y, basis, steps, jacobian_every)

    def one(measured):
        p = dataclasses.replace(problem, measured=measured)
        pc = dataclasses.replace(p, free=frees[0])
        begin = y0[None]
        if restarts.shape[0]:
            moved, moved_cost = jax.vmap(pc.start)(y0[:n_names] + restarts)
            moved_cost = jnp.where(jnp.isfinite(moved_cost), moved_cost, jnp.inf)
            begin = jnp.stack([y0, moved[jnp.argmin(moved_cost)]])
        ycs, ccs = jax.vmap(lambda y: refit(pc, y, control_basis, 2 * steps))(begin)
        yc, cc = ycs[jnp.argmin(ccs)], jnp.min(ccs)
        if entries.shape[0]:

            def profiled(entry, free):
                z = jnp.where(jnp.isnan(entry), yc, entry)[:n_names]
                y, cost = dataclasses.replace(p, free=free).start(z)
                return y, jnp.where(jnp.isfinite(cost), cost, jnp.inf)

            chosen, profiled_cost = jax.vmap(profiled)(entries, entry_free)

        def job(start, free, basis, rank, owner):
            pj = dataclasses.replace(p, free=free)
            y = jnp.where(jnp.isnan(start), yc, start)
            if entries.shape[0]:
                mine = jnp.where(entry_owner == owner, profiled_cost, jnp.inf)
                pick = jnp.argsort(mine)[jnp.maximum(rank, 0)]
                y = jnp.where(rank >= 0, chosen[pick], y)
            return refit(pj, y, basis, steps)

        yj, cj = jax.vmap(job)(starts, frees[1:], job_bases, ranks, job_owner)

        def control_from(cand):
            mine = jnp.where(job_owner == cand, cj, jnp.inf)
            best = jnp.argmin(mine)
            y, cost = refit(pc, jnp.where(kept, yj[best], y0), control_basis, steps)
            return y, jnp.where(jnp.isfinite(mine[best]), cost, jnp.inf)

        def padding(cand):
            return jnp.zeros_like(yc), jnp.asarray(jnp.inf, cc.dtype)

        # one candidate after another: ``members`` is the same on every recording, so a
        # padding slot (-1) skips its refit instead of running it masked beside the others
        ys, costs = jax.lax.map(
            lambda cand: jax.lax.cond(cand >= 0, control_from, padding, cand), members
        )
        best = jnp.argmin(costs)
        better = costs[best] < cc
        yc, cc = jnp.where(better, ys[best], yc), jnp.where(better, costs[best], cc)
        below = cj <= cc
        return cc, yc, jnp.where(below, cj, cc), jnp.where(below[:, None], yj, yc)

    return jax.vmap(one)(data)


def _shares(n_recordings: int) -> list:
    """The devices (`group_devices`) of the shares into which ``n_recordings`` recordings
    are split, equal shares of consecutive rows: one share per device of the default
    backend where the count divides among them, else one share."""
    n = len(jax.devices())
    return group_devices(n if n_recordings % n == 0 else 1)


def _start_values(cand: Candidate, model, whole_circle: bool = False) -> list[dict]:
    """The candidate's fixed starts: its tested parameters a step off their off-values (a
    third of their search scale; two-sided single parameters at the off-value), over a
    lattice of four grid settings and its directions (a modulation: two phases a quarter
    cycle apart; from one phase alone its refit on syn_base falls 0 % where from two it
    falls 12 %). With ``whole_circle``, the directions' phases are three spread over the
    whole cycle (a one-sided size, such as a modulation's depth, does not reach the
    opposite phase through zero)."""

    def scale(name):
        return (search_range(model, name) or (0.0, 1.0, 0.1))[2]

    step = cand.one_sided or len(cand.grid) > 1 or len(cand.directions) > 1
    tested = {t: cand.point[t] + (scale(t) / 3 if step else 0.0) for t in cand.tested}
    if len(cand.grid) == 1 and len(cand.directions) == 1:
        return [{**cand.grid[0], **cand.directions[0], **tested}]
    grid = [cand.grid[int(i)] for i in np.linspace(0, len(cand.grid) - 1, min(4, len(cand.grid)))]
    directions = cand.directions
    if whole_circle and len(directions) > 1:
        third = 2.0 * math.pi / 3.0
        directions = [{**directions[0], **t} for t in cand.turned((0.0, third, -third))]
    return [{**g, **d, **tested} for g in grid for d in directions]


def _coordinates(problem, values: dict, fill: float = math.nan) -> np.ndarray:
    """The search coordinates of parameter ``values`` in ``problem`` (``fill`` for those
    not given; 0 is the problem's reference point)."""
    z = np.full(len(problem.names), fill)
    linear, reference, scale = (
        np.asarray(a) for a in (problem.linear, problem.reference, problem.scale)
    )
    for i, n in enumerate(problem.names):
        if n in values:
            if linear[i]:
                z[i] = (values[n] - reference[i]) / scale[i]
            else:
                z[i] = math.log(values[n] / reference[i])
    return z


def _single_basin(cand: Candidate) -> bool:
    """Whether the candidate's error has one basin near the control (no grid of settings
    and no directions to try, unlike a modulation's frequency and phase)."""
    return len(cand.grid) == 1 and len(cand.directions) == 1


def _fit_point(problem, result: FitResult) -> np.ndarray:
    """The point of ``problem`` (the fit's sampling, its model extended by effects held
    off) where its model is ``result``'s fitted model at its time shift."""
    y = np.r_[_coordinates(problem, result.params, 0.0), result.time_shift / float(problem.period)]
    if problem.fit_s:
        y = np.r_[y, math.log(result.params["S"] / float(problem.s_reference))]
    return y


def _point_of(problem, fit: FitResult) -> np.ndarray:
    """The point of ``problem`` where its model is ``fit``'s (its effects held off but those
    ``fit`` has): exact where ``fit`` has the problem's warm-up (`_fit_point`); else the
    fitted parameters with the time shift found afresh on the grid of shifts (a longer
    warm-up moves the phase of the cycle at the first frame) and S projected."""
    if fit.sampling.warmup == float(problem.grid.t_start):
        return _fit_point(problem, fit)
    z = _coordinates(problem, fit.params, 0.0)
    return np.asarray(start_point(problem, np.asarray(z, dtype=float))[0])


def refit_groups(
    result: FitResult,
    recording: Recording,
    cands,
    estimates,
    calibration: Calibration = DEFAULT_CALIBRATION,
    anchor=None,
) -> list:
    """The statistic's refits of ``result`` on ``recording``, in groups of one warm-up each
    (`refit_jobs`): the candidates that need no longer warm-up than the fit's are refitted
    in the fit's own sampling, from the fit's point; those that do (a slow modulation's
    ``min_warmup``), in theirs, from the control refitted there (`settled`, twice
    ``calibration.steps`` steps). Each candidate's statistic compares its refit with the
    control of its own group. ``calibration``: the refits' steps, pool and control starts.

    Every group refits the same model (extended by every candidate, held off but its own)
    with as many jobs (padded with copies of the control, owner -1), so that one compiled
    program serves them all: the warm-up is data."""
    warmups = [max(result.sampling.warmup, float(type(c.term).min_warmup)) for c in cands]
    levels = sorted(set(warmups))
    groups = [
        refit_jobs(
            result,
            recording,
            cands,
            estimates,
            [k for k in range(len(cands)) if warmups[k] == w],
            w,
            anchor,
            calibration,
        )
        for w in levels
    ]
    n_jobs = max(len(g.owner) for g in groups)
    width = max(g.bases.shape[1] for g in groups)
    n_entries = max(g.pool.shape[0] for g in groups)
    out = []
    for g, w in zip(groups, levels):
        pad = n_jobs - len(g.owner)
        more = n_entries - g.pool.shape[0]
        bases = np.pad(g.bases, ((0, 0), (0, width - g.bases.shape[1]), (0, 0)))
        g = dataclasses.replace(
            g,
            starts=_padded(g.starts, pad, np.nan),
            frees=_padded(g.frees, pad, g.frees[0]),
            bases=_padded(bases, pad, bases[0]),
            owner=g.owner + (-1,) * pad,
            pool=_padded(g.pool, more, np.nan),
            pool_free=_padded(g.pool_free, more, g.frees[0]),
            pool_owner=_padded(g.pool_owner, more, -1),
            rank=_padded(g.rank, pad, -1),
        )
        if w != result.sampling.warmup:
            g = settled(g, calibration.steps, calibration.jacobian_every)
        out.append(g)
    return out


def refit_jobs(
    result: FitResult,
    recording: Recording,
    cands,
    estimates,
    members,
    warmup: float,
    anchor: dict | None = None,
    calibration: Calibration = DEFAULT_CALIBRATION,
) -> _Jobs:
    """The statistic's refits of ``result`` on ``recording`` for the candidates ``members``
    (indices into ``cands``) at ``warmup`` (s): the model extended by every candidate (held
    at their off-values), the control, and each member's starts, the same for every
    recording the statistic is computed on:

    - the fixed lattice of `_start_values` from the control's optimum;
    - for a candidate with a single basin, its fit on the recording (``estimates[k]``, a
      `FitResult` of the model with it, such as the search's refit) where that fit is
      better than ``result``, else the control's optimum with the effect off;
    - for a candidate with many basins (a grid of settings or several directions: the
      modulation's frequency and phase), given an ``anchor`` (`anchor_values`: the fitted
      parameters in the recording's starting model), a pool of starts: the lattice with
      the fitted parameters at the anchor and phases over the whole cycle. On each
      recording every entry's time shift and S are found afresh (`Problem.start`: the
      control's shift does not align the cycles of a model that far from it) and the
      ``calibration.pool`` entries of lowest cost so profiled are refitted.

    The control's extra starts: ``calibration.control_starts`` offsets of its fitted
    parameters' coordinates, a scrambled Halton design over the cube of half-width
    ``calibration.control_spread`` (the same for every recording), after a zero offset.

    A fit without the effect can bend the fitted parameters far from where the effect needs
    them (a closure hold stretched to imitate a pressure modulation's skipped closures: on
    vfjax's N1 with a modulation of 10 % at 8 Hz, seed 1 of the injection-recovery
    benchmark at 1 px, 8.7 ms where the starting model's is 5.6 ms), and ten steps from
    the control's optimum stay in its basin: there the lattice's best refit removes 8 % of
    the error, the pool's 58 % and the search's 94 % (the refits of all twelve entries
    reach the same 58 % as the best four, the best two 29 %). The lattice's few steps also
    stop short of an effect that moves the other parameters along the valleys where they
    trade off (on N1 with a cubic stiffness of 1 500 the lattice's refit keeps eta at 0
    where the search's removes half of the error), so the statistic would miss what the
    search sees. The search's point is chosen on the recording, and a null recording
    refitted from it can fall less than the recording does; where the error has a single
    basin near the control, a null recording without the effect finds the same optimum from
    the lattice, and the favour is small (the injection-recovery benchmark's false-alarm
    rate measures it). A candidate with many basins never starts from its search's point:
    there the search's choice of the best basin on the recording is a look-elsewhere
    favour (on an N3 recording without any effect, seed 1 at 1 px, that start gave the
    modulation p = 1/112)."""
    wide = extended(result.model, cands)
    if wide is None:
        raise ValueError("the candidates' parameter names clash: calibrate them one by one")
    fitted = tuple(result.params)
    union = fitted + tuple(
        dict.fromkeys(n for c in cands for n in c.tested + c.extra if n not in fitted)
    )
    sampling = dataclasses.replace(result.sampling, warmup=warmup)
    period = 1.0 / fundamental_frequency(recording.area, recording.fps)
    problem, _, _ = prepare(wide, recording, union, sampling, period, None)
    names = problem.names

    def coords(values):
        free = _coordinates(problem, values)
        return np.r_[free, np.full(problem.point_size - len(free), np.nan)]

    y0 = _point_of(problem, result)
    frees = [[1.0 if n in fitted else 0.0 for n in names]]
    restarts = _control_restarts(np.asarray(frees[0]) > 0, calibration)
    picked = calibration.pool
    starts, owner, ranks = [], [], []
    pool, pool_free, pool_owner = [], [], []
    for k in members:
        c = cands[k]
        own = set(fitted) | set(c.tested + c.extra)
        free = [1.0 if n in own else 0.0 for n in names]
        begin = [coords(s) for s in _start_values(c, wide)]
        rank = [-1] * len(begin)
        if picked and anchor and not _single_basin(c):
            fixed = {n: v for n, v in anchor.items() if n in fitted}
            around = [coords({**s, **fixed}) for s in _start_values(c, wide, whole_circle=True)]
            pool += around
            pool_free += [free] * len(around)
            pool_owner += [k] * len(around)
            begin += [np.full(y0.size, np.nan)] * picked
            rank += list(range(picked))
        if _single_basin(c):
            found = None if estimates is None else estimates[k]
            if found is not None and found.nmse < result.nmse:
                begin.append(_point_of(problem, found))
            else:
                begin.append(np.full(y0.size, np.nan))
            rank.append(-1)
        ranks += rank
        for b in begin:
            starts.append(b)
            frees.append(free)
            owner.append(k)
    # each refit's search directions: its free parameters, the time shift and S, then zero
    # rows of padding (`Problem.residual_and_jacobian`: the last rows move no physical one)
    n_y = y0.size
    movable = [np.r_[f, np.ones(n_y - len(names))] for f in frees]
    width = int(max(m.sum() for m in movable))
    bases = np.zeros((len(frees), width, n_y))
    for i, m in enumerate(movable):
        idx = np.flatnonzero(m)
        bases[i, np.arange(idx.size), idx] = 1.0
    return _Jobs(
        problem,
        np.asarray(y0),
        np.array(starts),
        np.array(frees),
        bases,
        tuple(owner),
        np.array(pool).reshape(len(pool), y0.size),
        np.array(pool_free).reshape(len(pool), len(names)),
        np.array(pool_owner, dtype=np.int32),
        np.array(ranks, dtype=np.int32),
        restarts,
    )


def _control_restarts(free: np.ndarray, calibration: Calibration) -> np.ndarray:
    """The control's extra starts as offsets of the search coordinates (`refit_jobs`): a
    zero row, then ``calibration.control_starts`` points of a scrambled Halton design in
    the cube of half-width ``calibration.control_spread`` over the coordinates where
    ``free``; none without control starts."""
    count = calibration.control_starts
    if count == 0 or not free.any():
        return np.zeros((0, free.size))
    unit = qmc.Halton(int(free.sum()), scramble=True, seed=calibration.seed).random(count)
    offsets = np.zeros((1 + count, free.size))
    offsets[1:, free] = (2.0 * unit - 1.0) * calibration.control_spread
    return offsets


def _padded(x: np.ndarray, rows: int, fill) -> np.ndarray:
    """``x`` with ``rows`` more rows of ``fill`` (a value or a row), in ``x``'s dtype."""
    more_rows = np.broadcast_to(np.asarray(fill, x.dtype), (rows, *x.shape[1:]))
    return np.concatenate([x, more_rows])


def _control_basis(bases) -> np.ndarray:
    """The control's search directions alone (``bases[0]`` without the zero rows that pad
    it to the jobs' width): each row costs a Jacobian column at every step."""
    rows = np.any(np.asarray(bases[0]) != 0, axis=1)
    return bases[0][rows]


def _members(owner, n_cands: int) -> np.ndarray:
    """The candidates among the jobs' owners, padded with -1 to ``n_cands`` (one shape, and
    so one compiled program, for every group)."""
    found = sorted({o for o in owner if o >= 0})
    return np.array(found + [-1] * (n_cands - len(found)))


def run_statistics(groups, data: np.ndarray, calibration: Calibration, n_cands: int):
    """The statistic of every group's refits on the recordings ``data`` (rows): each
    candidate's control NMSE (recordings, candidates): its group's, or the first group's
    (the fit's sampling) where that is lower; each candidate's best refit NMSE (recordings,
    candidates) and the points of those refits (per candidate, an array (recordings, n_y)
    in its group's coordinates). ``calibration``: the refits' steps and Jacobians."""
    controls = np.full((len(data), n_cands), np.nan)
    best_cost = np.full((len(data), n_cands), np.inf)
    best_y = [None] * n_cands
    devices = _shares(len(data))
    parts = np.split(np.asarray(data), len(devices))
    for jobs in groups:
        args = (
            jobs.problem,
            jobs.y0,
            jobs.starts,
            jobs.frees,
            (_control_basis(jobs.bases), jobs.bases[1:]),
            (
                jobs.pool,
                jobs.pool_free,
                jobs.pool_owner,
                jobs.rank,
                np.asarray(jobs.owner, dtype=np.int32),
                np.asarray(_members(jobs.owner, n_cands), dtype=np.int32),
            ),
            jobs.restarts,
        )
        # each share of the recordings refitted with the one-device program, in a thread of
        # its own: a recording's statistic has the same bits on any number of devices
        out = side_by_side(
            [
                lambda d=d, rows=rows, a=args: _statistics(
                    *placed((*a, rows), d), calibration.steps, calibration.jacobian_every
                )
                for d, rows in zip(devices, parts)
            ]
        )
        cc, _, cj, yj = (np.concatenate([np.asarray(o[i]) for o in out]) for i in range(4))
        owner = np.asarray(jobs.owner)
        for k in np.unique(owner[owner >= 0]):
            rows = np.flatnonzero(owner == k)
            finite = np.where(np.isfinite(cj[:, rows]), cj[:, rows], np.inf)
            pick = rows[np.argmin(finite, axis=1)]
            controls[:, k] = cc
            best_cost[:, k] = cj[np.arange(len(data)), pick]
            best_y[k] = yj[np.arange(len(data)), pick]
    # a candidate refitted after a longer warm-up answers to the best model without any
    # effect, in whichever sampling: the control after its warm-up can fit the recording far
    # worse than the fit's own (a state at the first frame that a longer warm-up moves into
    # another regime, near a grazing closure), and a fall from there is no evidence
    first = groups[0].owner[0]  # a candidate of the first group
    return np.minimum(controls, controls[:, first : first + 1]), best_cost, best_y


def f_p_values(control, refit, n_frames: int, n_fitted: int, dofs) -> np.ndarray:
    """The F test's p-value of each refit's error fall (a monotone standardisation across
    candidates of different degrees of freedom; the calibration, not the F distribution,
    gives the verdict's p-values)."""
    refit = np.asarray(refit, float)
    control = np.asarray(control, float)
    if control.ndim < refit.ndim:  # one control for every candidate
        control = control[..., None]
    dofs = np.asarray(dofs, float)
    resid = np.maximum(n_frames - n_fitted - dofs, 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        f = np.maximum(control - refit, 0.0) / dofs / (refit / resid)
    f = np.where(np.isfinite(f), f, np.where(refit < control, np.inf, 0.0))
    return stats.f.sf(f, dofs, resid)


def _statistic(q) -> np.ndarray:
    """The test statistic of F-test p-values ``q``: -log q."""
    return -np.log(np.maximum(np.asarray(q, float), 1e-300))


#: The spread of the statistic, -log of an F test's p-value, where the F distribution holds
#: (an exponential of mean 1): its 90th percentile less its median, ln 10 - ln 2.
_REFERENCE_SPREAD = math.log(5.0)


def family_p_values(q_obs, nulls_q):
    """Calibrated p-values of the candidates' F-test p-values on the recording, ``q_obs``
    (candidates,), against those on null recordings, ``nulls_q`` (nulls, candidates): the
    family-wise ones, the marginal ones, each null recording's largest standardised
    statistic and the recording's standardised statistics.

    A step of max-T (Westfall and Young) on standardised statistics: each candidate's
    statistic, -log of its F-test p-value (a scale common to candidates of different
    dimension), less its median over the recording and the null recordings, over its spread
    there (its 90th percentile less its median) in units of the spread it has where the F
    distribution holds, and never less than that unit. Centred, a candidate whose refit falls
    far on every recording does not mask the others; scaled, neither does one whose refit
    falls far on a few (a modulation that takes up a null recording's wandering periods),
    while a candidate whose null recordings spread no more than the F distribution makes
    them keeps its F-test scale. The centre and spread are functions of the pooled
    statistics, the same whichever of them is the recording's: where the recording is
    exchangeable with its null recordings (no effect), the p-values are valid. A candidate's
    family-wise p-value is (1 + null recordings whose largest standardised statistic reaches
    its own) / (1 + null recordings)."""
    obs, nulls = _statistic(q_obs), _statistic(nulls_q)
    n = len(nulls)
    pooled = np.concatenate([obs[None], nulls])
    centre = np.median(pooled, axis=0)
    spread = (np.quantile(pooled, 0.9, axis=0) - centre) / _REFERENCE_SPREAD
    z = (pooled - centre) / np.maximum(spread, 1.0)
    largest = z[1:].max(axis=1)
    family = (1 + (largest[:, None] >= z[0][None, :]).sum(axis=0)) / (n + 1)
    marginal = (1 + (nulls >= obs[None, :]).sum(axis=0)) / (n + 1)
    return family, marginal, largest, z[0]
