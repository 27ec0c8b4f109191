"""Injection-recovery: how often the calibrated diagnosis finds an effect hidden in a
recording, and how often it flags one that is not there.

Recordings made by vfjax (201 frames at 4 kHz, rounded to whole pixels and clipped at 0) in
sustained phonation (from 0.5 s after the onset, `--warmup`, where every effect's oscillation
has settled): the paper's model for a male (N1) and a female (N3) subject, with realistic
cycle-to-cycle variability (timing offsets of 30 us and amplitude factors of 2 % standard
deviation per cycle, `TimingJitter` and `AmplitudeJitter`, and closure-duration jitter of
0.3 %, `ClosureJitter`) and white noise of 1 or 3 px; each catalogue effect at three strengths
(chosen by the oracle below, `--oracle`: the weakest near the detection limit), three seeds
each, and recordings with no effect (ten seeds per subject and noise; and twelve of the cohort
benchmark's kind, `COHORT_NULLS`: N2 and N4, 101 frames at 2 kHz and 201 at 4 kHz, closure
jitter alone, 1 px). Each is fitted as the command line does (`vfjax.fit_recording`) and
diagnosed with the defaults (`vfjax.diagnose`).

Per effect and strength: the detection rate (the true effect is needed), how often the true
effect ranks first among the needed ones, the recovered value over the truth (the gap's area
times S, the modulation's depth times P_s: what the GAW fixes), how often its
interval holds the truth, how often another effect is needed too (an effect partly explains
another's misfit: the diagnosis's first is the one to add, the others are tested again after
it), and the oracle: the share of the error that the true structure at its true values
(polished from there) removes from the paper model's fit, the best any test could see. The
false-alarm rate is the share of no-effect recordings where anything is needed; beside it,
how often the fit's own error lies beyond every null recording's (`Calibrated.fit_p_value`
at most 0.01: a misfit the null recordings lack, which on a no-effect recording is a false
alarm of its own kind).

Resumable: each recording's outcome (with the commit that made it) is appended to a
JSON-lines file (``--out``) as soon as it is done; a rerun skips what is there and prints the
table from all of it. Recordings run seed by seed (every effect, strength, subject and noise
of seed 0 first), so that a partial run covers every case alike.

``--oracle`` measures what chooses the strengths instead: the oracle fall of every effect at
each size of `ORACLE_SIZES`, both subjects and noises, seed 0, and prints its table (its own
results file, ``diagnosis_oracle.jsonl`` by default).

Run: python benchmarks/diagnosis_power.py [--out FILE] [--only EFFECT|none|cohort-none]
[--strength weak|medium|strong] [--seed S] [--limit N] [--pool N] [--search-nulls N|all]
[--no-interval-search] [--warmup S] [--oracle]
"""

import argparse
import json
import math
import pathlib
import subprocess
import time

import numpy as np

import vfjax
from vfjax.cli import _search_nulls, use_cpu_cores
from vfjax.datasets import demo_recording, demo_span, factors_duration

FPS = 4000.0
N_FRAMES = 201
SUBJECTS = ("N1", "N3")  # male, female
NOISE_PX = (1.0, 3.0)
SEEDS = (0, 1, 2)
NULL_SEEDS = tuple(range(10))
#: No-effect recordings of the cohort benchmark's kind (benchmarks/cohort.py): the other two
#: subjects, (frame rate, frames) of its shortest recordings, closure-duration jitter alone
#: (a steady voice: the variability is at most the noise's), 1 px, three seeds each.
COHORT_NULLS = {"subjects": ("N2", "N4"), "samplings": ((2000.0, 101), (4000.0, 201))}
COHORT_NULL_SEEDS = (0, 1, 2)
TIMING_SD = 30e-6  # s
AMPLITUDE_SD = 0.02
CLOSURE_JITTER = 0.003
#: Simulated time before a recording's first frame (s): sustained phonation. Every effect's
#: oscillation has settled by then; a cubic stiffness's amplitude drifts for more than 0.2 s.
WARMUP = 0.5
#: `vfjax.Calibration`'s default count of null recordings searched alike (`--search-nulls`).
DEFAULT_SEARCH_NULLS = vfjax.Calibration().search_nulls
#: effect -> (parameter, weak, medium, strong, how to build it). Chosen by the oracle fall
#: (`--oracle`, benchmarks/README.md): the weak strength removes a tenth to a third of the
#: first fit's error (median over subjects and noises), the medium about half or more
#: where the effect can show in 50 ms. A settled cubic stiffness is mostly absorbed by K
#: (its oracle stays under a third up to eta 12 000), and a pressure modulation on N3 is
#: invisible below a depth of 0.2.
EFFECTS = {
    "GlottalGap": ("a_gap", (0.001, 0.003, 0.008), lambda v, s: vfjax.GlottalGap(a_gap=v)),
    "CubicStiffness": (
        "eta",
        (3000.0, 6000.0, 12000.0),
        lambda v, s: vfjax.CubicStiffness(eta=v),
    ),
    "PressureModulation": (
        "a_pm",
        (0.1, 0.2, 0.4),
        lambda v, s: vfjax.PressureModulation(a_pm=v, f_m=8.0, phi=-2.0 + 1.7 * s),
    ),
    "MucosalDelay": ("tau", (2e-4, 4e-4, 8e-4), lambda v, s: vfjax.MucosalDelay(tau=v)),
}
#: The sizes the oracle sweep (`--oracle`) measures, per effect.
ORACLE_SIZES = {
    "GlottalGap": (0.001, 0.003, 0.008, 0.02),
    "CubicStiffness": (1500.0, 3000.0, 6000.0, 12000.0),
    "PressureModulation": (0.05, 0.1, 0.2, 0.4),
    "MucosalDelay": (1e-4, 2e-4, 4e-4, 8e-4),
}
STRENGTHS = ("weak", "medium", "strong")
#: Effects whose size the GAW fixes only times another parameter (the camera scale S, px per
#: mm², or the pressure P_s, dyne/cm²): the gap's area in pixels, the modulation's amplitude
#: in dyne/cm² (S, P_s and the folds' amplitude trade off along a valley of the error).
SCALED = {"GlottalGap": "S", "PressureModulation": "P_s"}


def cases():
    """Every recording of the benchmark: (key, subject, effect name or None, strength index,
    noise, seed, sampling), ``sampling`` None for 201 frames at 4 kHz with the benchmark's
    variability, else the (frame rate, frames) of a no-effect recording of the cohort's kind
    (`COHORT_NULLS`)."""
    out = []
    for subject in COHORT_NULLS["subjects"]:
        for fps, frames in COHORT_NULLS["samplings"]:
            for seed in COHORT_NULL_SEEDS:
                key = f"none/{subject}/{frames}f-{fps / 1000:g}kHz/closure/1px/{seed}"
                out.append((key, subject, None, None, 1.0, seed, (fps, frames)))
    for subject in SUBJECTS:
        for noise in NOISE_PX:
            for seed in NULL_SEEDS:
                key = f"none/{subject}/{noise:g}px/{seed}"
                out.append((key, subject, None, None, noise, seed, None))
            for effect in EFFECTS:
                for k, strength in enumerate(STRENGTHS):
                    for seed in SEEDS:
                        key = f"{effect}/{strength}/{subject}/{noise:g}px/{seed}"
                        out.append((key, subject, effect, k, noise, seed, None))
    return sorted(out, key=lambda c: c[5])  # seed by seed (a stable sort)


def _family(case) -> str:
    """A case's effect, ``none`` or ``cohort-none`` (`COHORT_NULLS`), for ``--only``."""
    return case[2] or ("none" if case[6] is None else "cohort-none")


def make_recording(subject, effect, size, noise, seed, warmup=WARMUP, sampling=None):
    """The recording of one case, and the true model (None without an effect). ``size``: the
    effect's parameter (`EFFECTS`); ``warmup``: simulated time before its first frame (s;
    None: `demo_recording`'s, a start-up); ``sampling``: None for the benchmark's frames and
    variability, else (frame rate, frames) with closure-duration jitter alone."""
    if sampling is not None:
        fps, frames = sampling
        rec = demo_recording(
            subject, noise, seed, fps, frames, jitter=CLOSURE_JITTER, warmup=warmup
        )
        return rec, None
    model = vfjax.preset(subject)
    term = None
    if effect is not None:
        _, _, build = EFFECTS[effect]
        term = build(size, seed)
        model = model.with_effect(term)
    f0 = vfjax.descriptors.fundamental_frequency(
        np.asarray(vfjax.simulate(model, FPS, 400, t_start=0.05).area), FPS
    )
    period = 1.0 / f0
    _, end = demo_span(model, FPS, N_FRAMES, warmup)
    covered = factors_duration(end, period)  # the recording's cycles
    jittered = model.with_term(
        vfjax.TimingJitter.random(TIMING_SD, period, duration=covered, seed=seed + 11)
    )
    jittered = jittered.with_term(
        vfjax.AmplitudeJitter.random(AMPLITUDE_SD, period, duration=covered, seed=seed + 23)
    )
    rec = demo_recording(
        subject,
        noise_px=noise,
        seed=seed,
        fps=FPS,
        n_frames=N_FRAMES,
        jitter=CLOSURE_JITTER,
        model=jittered,
        warmup=warmup,
    )
    return rec, (model if term is not None else None)


def oracle_fall(truth, rec, first, effect: str, warmup=WARMUP) -> float:
    """Share of the first fit's error that the true structure, polished from its true values
    (the first fit's parameters and the effect's), removes: after the true model's default
    warm-up (its time shift fitted), or from the recording's own start where ``warmup`` (s)
    gives it."""
    kind = getattr(vfjax, effect)
    params = tuple(first.params) + tuple(n for n in kind.parameters if n not in first.params)
    start = {} if warmup is None else {"warmup": warmup}
    best = vfjax.fit(
        truth, rec, params=params, swarm=vfjax.Swarm(iterations=0), progress=False, **start
    )
    return 1.0 - best.nmse / first.nmse


def _commit() -> str:
    """The checkout's commit (with ``+`` when it has changes), or ``unknown``."""
    here = pathlib.Path(__file__).parent
    try:
        head = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], cwd=here, capture_output=True, text=True
        ).stdout.strip()
        dirty = subprocess.run(
            ["git", "status", "--porcelain", "--untracked-files=no"],
            cwd=here,
            capture_output=True,
            text=True,
        ).stdout.strip()
    except OSError:
        return "unknown"
    return (head + ("+" if dirty else "")) or "unknown"


COMMIT = _commit()


def run_case(case, calibration=None, warmup=WARMUP) -> dict:
    key, subject, effect, strength, noise, seed, sampling = case
    calibration = calibration or vfjax.Calibration()
    size = None if effect is None else EFFECTS[effect][1][strength]
    rec, truth = make_recording(subject, effect, size, noise, seed, warmup, sampling)
    t0 = time.perf_counter()
    first = vfjax.fit_recording(rec, progress=False)
    d = vfjax.diagnose(first, rec, calibration=calibration)
    row = {
        "key": key,
        "subject": subject,
        "effect": effect,
        "strength": None if strength is None else STRENGTHS[strength],
        "noise_px": noise,
        "seed": seed,
        "fps": rec.fps,
        "n_frames": rec.n_frames,
        "variability": "closure" if sampling is not None else "benchmark",
        "seconds": time.perf_counter() - t0,
        "commit": COMMIT,
        "first_nmse": first.nmse,
        "needed": d.needed,
        "unconfirmed": d.unconfirmed,
        "search_p_values": {n: f.search_p_value for n, f in d.refits.items()},
        "searched_nulls": dict(zip(d.calibrated.candidates, d.calibrated.searched_nulls))
        if d.calibrated is not None
        else {},
        "ranking": d.ranking,
        "p_values": {n: f.p_value for n, f in d.refits.items()},
        "replicates": d.calibrated.replicates if d.calibrated is not None else None,
        # the fit's calibrated goodness: the recording's control against the null recordings'
        "fit_p_value": d.calibrated.fit_p_value if d.calibrated is not None else None,
        # the null recordings' variability: timing offsets (s), amplitude factors, periods (s)
        "null_spreads": [
            d.calibrated.variability.timing_sd,
            d.calibrated.variability.amplitude_sd,
            d.calibrated.variability.period_sd,
        ]
        if d.calibrated is not None
        else None,
        "pool": calibration.pool,
        "search_nulls": calibration.search_nulls,
        "interval_search": calibration.interval_search,
        "warmup": warmup,
    }
    if effect is not None:
        name, values, _ = EFFECTS[effect]
        refit = d.refits.get(effect)
        row["truth"] = values[strength]
        row["recovered"] = refit.values.get(name) if refit is not None else None
        interval = (refit.interval or {}).get(name) if refit is not None else None
        row["interval"] = list(interval) if interval is not None else None
        # the interval's bootstrap distribution: the size refitted on each replicate
        cal = d.calibrated
        kept = {}
        if cal is not None and cal.bootstrap_values and effect in cal.candidates:
            kept = cal.bootstrap_values[cal.candidates.index(effect)] or {}
        drawn = kept.get(name)
        row["bootstrap"] = list(drawn) if drawn is not None else None
        if drawn is not None and SCALED.get(effect) in kept:  # the GAW's size on each one
            scales = kept[SCALED[effect]]
            row["bootstrap_scaled"] = [v * s for v, s in zip(drawn, scales)]
        row["oracle_fall"] = oracle_fall(truth, rec, first, effect, warmup)
        if refit is not None and effect in SCALED:
            # what the GAW fixes: the size times a parameter it trades off against
            other = SCALED[effect]
            fitted = float(refit.result.model.params()[other])
            row["recovered_scaled"] = row["recovered"] * fitted
            row["truth_scaled"] = row["truth"] * float(truth.params()[other])
            if row["interval"] is not None:  # the other parameter's own spread left out
                row["interval_scaled"] = [v * fitted for v in row["interval"]]
    return row


def summary(rows):
    print(f"{len(rows)} recordings")
    nulls = [r for r in rows if r["effect"] is None]
    if nulls:
        alarms = sum(bool(r["needed"]) for r in nulls)
        print(f"no effect: false alarms {alarms}/{len(nulls)} ({alarms / len(nulls):.0%})")
        for kind, words in (("benchmark", "N1, N3"), ("closure", "the cohort's kind")):
            some = [r for r in nulls if r.get("variability", "benchmark") == kind]
            if some:
                flagged = sorted(f"{r['key']}: {r['needed']}" for r in some if r["needed"])
                print(
                    f"  {words}: {len(flagged)}/{len(some)}"
                    + "".join(f"\n    {f}" for f in flagged)
                )
        told = [r for r in nulls if "unconfirmed" in r]
        if told:
            flags = sum(bool(r["unconfirmed"]) for r in told)
            print(f"no effect: an unconfirmed search flagged on {flags}/{len(told)}")
        weighed = [r for r in nulls if r.get("fit_p_value") is not None]
        if weighed:  # at the level the recordings were diagnosed with (the default)
            alpha = vfjax.Criteria().alpha
            beyond = sorted(r["key"] for r in weighed if r["fit_p_value"] <= alpha)
            print(
                f"no effect: the fit's error beyond every null recording's on "
                f"{len(beyond)}/{len(weighed)}" + "".join(f"\n    {k}" for k in beyond)
            )
    print(
        "effect              strength  n  detected  first  recovered/truth (median)  "
        "interval holds truth  others needed  oracle fall (median)  s/recording  "
        "unconfirmed (true/any)"
    )
    for effect in EFFECTS:
        for strength in STRENGTHS:
            got = [r for r in rows if r["effect"] == effect and r["strength"] == strength]
            if not got:
                continue
            found = [r for r in got if effect in r["needed"]]
            first = [r for r in got if r["needed"] and r["needed"][0] == effect]
            flagged = [r for r in got if r["needed"]]
            ratio = [
                r["recovered_scaled"] / r["truth_scaled"]
                if "recovered_scaled" in r
                else r["recovered"] / r["truth"]
                for r in found
                if r["recovered"] is not None and r["truth"]
            ]
            others = [r for r in got if set(r["needed"]) - {effect}]
            held = [
                r["interval_scaled"][0] <= r["truth_scaled"] <= r["interval_scaled"][1]
                if "interval_scaled" in r
                else r["interval"][0] <= r["truth"] <= r["interval"][1]
                for r in found
                if r.get("interval") is not None
            ]
            print(
                f"{effect:19s} {strength:8s} {len(got):2d}  {len(found) / len(got):7.0%}  "
                f"{(len(first) / len(flagged)) if flagged else math.nan:5.0%}  "
                f"{np.median(ratio) if ratio else math.nan:24.2f}  "
                f"{f'{sum(held)}/{len(held)}':>20s}  "
                f"{len(others) / len(got):13.0%}  "
                f"{np.median([r['oracle_fall'] for r in got]):20.2%}  "
                f"{np.median([r['seconds'] for r in got]):11.0f}  "
                f"{unconfirmed(got, effect):>22s}"
            )


def unconfirmed(rows, effect) -> str:
    """Of the recordings that record it, where the true effect was not needed: how many
    name it unconfirmed, and how many name any effect unconfirmed (``true/any of n``)."""
    told = [r for r in rows if "unconfirmed" in r and effect not in r["needed"]]
    if not told:
        return "-"
    true = sum(effect in r["unconfirmed"] for r in told)
    return f"{true}/{sum(bool(r['unconfirmed']) for r in told)} of {len(told)}"


def read_rows(
    out: pathlib.Path, warmup, search_nulls=DEFAULT_SEARCH_NULLS, interval_search=True
) -> list[dict]:
    """The rows of a JSON-lines results file (none where it is missing); ValueError where it
    holds rows of another warm-up (s), another count of null recordings searched alike
    (``search_nulls``, None for all) or intervals refitted otherwise (``interval_search``),
    which a run must not mix or skip as done."""
    rows = [json.loads(x) for x in out.read_text().splitlines() if x] if out.exists() else []
    for option, value, default in (
        ("warmup", warmup, None),
        ("search_nulls", search_nulls, DEFAULT_SEARCH_NULLS),
        ("interval_search", interval_search, False),  # (a row without the field: by steps)
    ):
        other = {r.get(option, default) for r in rows} - {value}
        if other:
            held, flag = sorted(other, key=str), "--" + option.replace("_", "-")
            raise ValueError(f"{out} holds rows of another {flag} ({held}): use another --out")
    return rows


def oracle_sweep(out: pathlib.Path, rows: list[dict], warmup=WARMUP):
    """The oracle fall of every effect at each size of `ORACLE_SIZES`, on both subjects and
    noises (seed 0), appended to ``out`` (holding ``rows``) as it goes; prints the table."""
    done = {r["key"] for r in rows}
    for effect, sizes in ORACLE_SIZES.items():
        for size in sizes:
            for subject in SUBJECTS:
                for noise in NOISE_PX:
                    key = f"{effect}/{size:g}/{subject}/{noise:g}px"
                    if key in done:
                        continue
                    rec, truth = make_recording(subject, effect, size, noise, 0, warmup)
                    first = vfjax.fit_recording(rec, progress=False)
                    fall = oracle_fall(truth, rec, first, effect, warmup)
                    row = {"key": key, "effect": effect, "size": size, "subject": subject}
                    row.update(noise_px=noise, first_nmse=first.nmse, oracle_fall=fall)
                    row.update(warmup=warmup, commit=COMMIT)
                    with out.open("a") as f:
                        f.write(json.dumps(row) + "\n")
                    rows.append(row)
                    print(f"{key}: oracle fall {fall:.1%}", flush=True)
    print("effect              size     oracle fall: N1 1 px, N1 3 px, N3 1 px, N3 3 px  (median)")
    for effect, sizes in ORACLE_SIZES.items():
        for size in sizes:
            got = {
                (r["subject"], r["noise_px"]): r["oracle_fall"]
                for r in rows
                if r["effect"] == effect and r["size"] == size
            }
            falls = [got.get((s, n), math.nan) for s in SUBJECTS for n in NOISE_PX]
            cells = "  ".join(f"{f:6.1%}" for f in falls)
            print(f"{effect:19s} {size:<8g} {cells}  ({np.median(falls):.0%})")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--out",
        help="JSON-lines results file (default diagnosis_power.jsonl, with --oracle "
        "diagnosis_oracle.jsonl)",
    )
    ap.add_argument(
        "--only",
        help="one effect's cases, 'none' for the no-effect ones of N1 and N3, or "
        "'cohort-none' for those of the cohort's kind (COHORT_NULLS)",
    )
    ap.add_argument("--strength", choices=STRENGTHS, help="only this strength of the effects")
    ap.add_argument("--seed", type=int, help="only this seed's recordings")
    ap.add_argument("--limit", type=int, help="stop after this many new recordings")
    ap.add_argument(
        "--pool", type=int, default=0, help="vfjax.Calibration's pool (default 0: none)"
    )
    ap.add_argument(
        "--search-nulls",
        type=_search_nulls,
        default=DEFAULT_SEARCH_NULLS,
        metavar="N|all",
        help="vfjax.Calibration's search_nulls: a count, or 'all' (default %(default)s)",
    )
    ap.add_argument(
        "--interval-search",
        action=argparse.BooleanOptionalAction,
        default=vfjax.Calibration().interval_search,
        help="vfjax.Calibration's interval_search: refit the intervals' replicates by a "
        "search (default), or by the statistic's steps (--no-interval-search)",
    )
    ap.add_argument(
        "--warmup",
        type=float,
        default=WARMUP,
        help=f"simulated time before each recording's first frame, s (default {WARMUP}: "
        "sustained phonation; vfjax.datasets.demo_recording starts 7.7 ms after the "
        "model's default warm-up, 0.0277 s for most effects: a start-up)",
    )
    ap.add_argument(
        "--oracle",
        action="store_true",
        help="measure the oracle fall of every effect at the sizes of ORACLE_SIZES instead",
    )
    args = ap.parse_args()
    use_cpu_cores(None)
    default = "diagnosis_oracle.jsonl" if args.oracle else "diagnosis_power.jsonl"
    out = pathlib.Path(args.out or default)
    try:
        rows = read_rows(out, args.warmup, args.search_nulls, args.interval_search)
    except ValueError as e:
        ap.error(str(e))
    if args.oracle:
        oracle_sweep(out, rows, args.warmup)
        return
    done = {r["key"] for r in rows}
    todo = [c for c in cases() if c[0] not in done]
    if args.only:
        todo = [c for c in todo if _family(c) == args.only]
    if args.seed is not None:
        todo = [c for c in todo if c[5] == args.seed]
    if args.strength:
        todo = [c for c in todo if c[3] is None or STRENGTHS[c[3]] == args.strength]
    for case in todo[: args.limit]:
        calibration = vfjax.Calibration(
            pool=args.pool, search_nulls=args.search_nulls, interval_search=args.interval_search
        )
        row = run_case(case, calibration, args.warmup)
        with out.open("a") as f:
            f.write(json.dumps(row) + "\n")
        rows.append(row)
        print(f"{row['key']}: needed {row['needed']} ({row['seconds']:.0f} s)", flush=True)
    summary(rows)


if __name__ == "__main__":
    main()
