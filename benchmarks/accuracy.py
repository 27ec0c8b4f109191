"""Accuracy study: GAW error against a far finer reference, per RK4 step size.

For each parameter set (N1-N4, each also with K and C_f moved by ±30 % and ±80 %), the
201-frame GAW at dt = 1 / (k fps) for k in {1, 2, 4, 8, 16, 32, 64, 128} is compared with
vfjax at k = 1024 by NMSE = sum((a - ref)²) / sum(ref²). The paper's practice, a fixed step
at k = 128 with per-stage masks (benchmarks/numba_reference.py), is measured against the same
reference.

Run: python benchmarks/accuracy.py
"""

import pathlib
import sys

import jax
import jax.numpy as jnp
import numpy as np

import vfjax

sys.path.insert(0, str(pathlib.Path(__file__).parent))
FPS, N = 4000.0, 201
KS = (1, 2, 4, 8, 16, 32, 64, 128)
REF_K = 1024
VARIANTS = {"": (1.0, 1.0), " K-30%": (0.7, 1.0), " K+30%": (1.3, 1.0),
            " Cf-30%": (1.0, 0.7), " Cf+30%": (1.0, 1.3), " K-80%": (0.2, 1.0),
            " K+80%": (1.8, 1.0), " Cf-80%": (1.0, 0.2), " Cf+80%": (1.0, 1.8)}  # fmt: skip


def nmse(a, ref):
    return float(np.sum((np.asarray(a) - ref) ** 2) / np.sum(ref**2))


def main():
    from numba_reference import simulate_gaw

    factors = jnp.asarray(list(VARIANTS.values()))
    rows = []
    for name in ("N1", "N2", "N3", "N4"):
        model = vfjax.preset(name)
        p = model.params()

        def run(f, k, model=model, p=p):
            return vfjax.simulate(model.set(K=p["K"] * f[0], C_f=p["C_f"] * f[1]), FPS, N,
                                  substeps=k).area  # fmt: skip

        ref = np.asarray(jax.jit(jax.vmap(lambda f: run(f, REF_K)))(factors))
        per_k = {k: np.asarray(jax.jit(jax.vmap(lambda f, k=k: run(f, k)))(factors)) for k in KS}
        for i, label in enumerate(VARIANTS):
            q = {
                n: float(v)
                for n, v in model.set(K=p["K"] * factors[i, 0], C_f=p["C_f"] * factors[i, 1])
                .params()
                .items()
            }
            paper = simulate_gaw(q["K"], q["C_f"], q["S"], q["t_c"], q["P_s"], q["M"], q["l"],
                                 FPS, N, 128)  # fmt: skip
            rows.append((name + label, [nmse(per_k[k][i], ref[i]) for k in KS],
                         nmse(paper, ref[i])))  # fmt: skip

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


if __name__ == "__main__":
    main()
