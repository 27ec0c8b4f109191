"""Accuracy study: GAW error against a far finer reference, per RK4 step size.

For each parameter set (N1-N4, each also with K and C_f moved by ±30 % and ±80 %), the
201-frame GAW at dt = 1 / (k fps) for k in {1, 2, 3, 4, 6, 8, 16, 32, 64, 128} is compared with
vfjax at k = 1024 by NMSE = sum((a - ref)²) / sum(ref²). The paper's practice, a fixed step
at k = 128 with per-stage masks (benchmarks/numba_reference.py), is measured against the same
reference.

A second table samples each subject's ±80 % box in K, C_f, S, t_c and P_s at random (400 sets
each, reference k = 64) and counts the sets whose NMSE exceeds 1e-4 per k: how robust a step is
across the parameter space a fit explores, not only at the named sets.

Run: python benchmarks/accuracy.py [--box-sets 400]
"""

import argparse
import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

import vfjax

sys.path.insert(0, str(pathlib.Path(__file__).parent))
FPS, N = 4000.0, 201
KS = (1, 2, 3, 4, 6, 8, 16, 32, 64, 128)
BOX_KS = (3, 4, 6, 8)
REF_K = 1024
VARIANTS = {
    "": (1.0, 1.0),
    " K-30%": (0.7, 1.0),
    " K+30%": (1.3, 1.0),
    " Cf-30%": (1.0, 0.7),
    " Cf+30%": (1.0, 1.3),
    " K-80%": (0.2, 1.0),
    " K+80%": (1.8, 1.0),
    " Cf-80%": (1.0, 0.2),
    " Cf+80%": (1.0, 1.8),
}


def nmse(a, ref):
    return float(np.sum((np.asarray(a) - ref) ** 2) / np.sum(ref**2))


def box_study(n_sets, seed=0):
    """NMSE per k over random sets in each subject's ±80 % box (reference k = 64)."""
    rng = np.random.default_rng(seed)
    names = ("K", "C_f", "S", "t_c", "P_s")
    errors = {k: [] for k in BOX_KS}
    for subject in ("N1", "N2", "N3", "N4"):
        model = vfjax.preset(subject)
        p = model.params()
        factors = jnp.asarray(rng.uniform(0.2, 1.8, (n_sets, len(names))))

        def run(k, model=model, p=p, factors=factors):
            def one(f):
                m = model.set(**{n: p[n] * f[i] for i, n in enumerate(names)})
                return vfjax.simulate(m, FPS, N, substeps=k, throw=False).area

            return np.asarray(jax.jit(jax.vmap(one))(factors))

        ref = run(64)
        for k in BOX_KS:
            errors[k].extend(nmse(a, r) for a, r in zip(run(k), ref))
    print(
        f"\nRandom sets in the ±80 % box of K, C_f, S, t_c, P_s ({n_sets} per subject, "
        "reference k=64)"
    )
    print(
        "k".ljust(4)
        + "median".rjust(10)
        + "99th pct".rjust(10)
        + "worst".rjust(10)
        + "   sets with NMSE > 1e-4"
    )
    for k in BOX_KS:
        e = np.asarray(errors[k])
        print(
            f"{k:<4d}{np.median(e):10.1e}{np.percentile(e, 99):10.1e}{e.max():10.1e}"
            f"   {int(np.sum(e > 1e-4))} of {e.size}"
        )


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--box-sets", type=int, default=400, help="random sets per subject")
    args = ap.parse_args()
    from numba_reference import simulate_gaw

    factors = jnp.asarray(list(VARIANTS.values()))
    rows = []
    for name in ("N1", "N2", "N3", "N4"):
        model = vfjax.preset(name)
        p = model.params()

        def run(f, k, model=model, p=p):
            return vfjax.simulate(
                model.set(K=p["K"] * f[0], C_f=p["C_f"] * f[1]), FPS, N, substeps=k
            ).area

        ref = np.asarray(jax.jit(jax.vmap(lambda f: run(f, REF_K)))(factors))
        per_k = {k: np.asarray(jax.jit(jax.vmap(lambda f, k=k: run(f, k)))(factors)) for k in KS}
        for i, label in enumerate(VARIANTS):
            q = {
                n: float(v)
                for n, v in model.set(K=p["K"] * factors[i, 0], C_f=p["C_f"] * factors[i, 1])
                .params()
                .items()
            }
            paper = simulate_gaw(
                q["K"], q["C_f"], q["S"], q["t_c"], q["P_s"], q["M"], q["l"], FPS, N, 128
            )
            rows.append(
                (name + label, [nmse(per_k[k][i], ref[i]) for k in KS], nmse(paper, ref[i]))
            )

    head = "set".ljust(12) + "".join(f"k={k}".rjust(10) for k in KS) + "  paper k=128"
    print(f"NMSE against vfjax at k={REF_K} (dt = 1/(k fps), fps = {FPS:g}, {N} frames)")
    print(head)
    for label, errs, paper in rows:
        print(label.ljust(12) + "".join(f"{e:10.1e}" for e in errs) + f"{paper:13.1e}")
    worst = np.max([r[1] for r in rows], axis=0)
    print("worst".ljust(12) + "".join(f"{e:10.1e}" for e in worst))
    ok = [k for k, e in zip(KS, worst) if e < 1e-4]
    print(
        f"smallest k with NMSE < 1e-4 on every set: {min(ok) if ok else 'none'}; "
        f"vfjax default: {vfjax.DEFAULT_SUBSTEPS}"
    )
    if args.box_sets > 0:
        box_study(args.box_sets)


if __name__ == "__main__":
    main()
