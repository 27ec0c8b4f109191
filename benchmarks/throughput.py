"""Throughput: 201-frame recordings per second, vfjax (vmapped, jitted) against a scalar
numba loop of the same model at the paper's step (k = 128 steps per frame, one thread).

Figures printed, all in float64, from one run on the same machine:
- compile time of the batched simulator;
- recordings per second for batches of 1, 64 and 256 at vfjax's default step, on one core
  and with the batch split over the machine's cores (one XLA host device per core), either
  with `jax.shard_map` (one SPMD program) or one Python thread per device, each running the
  one-core program on its share (XLA releases the GIL while it runs);
- particle-steps per second at an equal step (k = 128 for both).

Each vfjax figure is timed alternately with the numba loop (best of ``--repeats`` each) and its
ratio is taken against the numba rate measured alongside it: on a shared machine whose load
drifts during the run, a ratio against a numba rate measured minutes earlier would mislead.

Run: python benchmarks/throughput.py [--repeats 7]
"""

import os

# One XLA host device per core, so that a batch can be split over the cores (this script's
# own process only; vfjax itself changes no XLA flag).
os.environ.setdefault("XLA_FLAGS", f"--xla_force_host_platform_device_count={os.cpu_count()}")

import argparse  # noqa: E402
import pathlib  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
from concurrent.futures import ThreadPoolExecutor  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import numpy as np  # noqa: E402
from jax.sharding import Mesh, NamedSharding, PartitionSpec  # noqa: E402

import vfjax  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).parent))
FPS, N = 4000.0, 201


def batch_of(model, n, seed=0):
    """``n`` copies of ``model`` with K, C_f, S, t_c scattered by ±10 %."""
    rng = np.random.default_rng(seed)
    p = model.params()
    scale = lambda name: jnp.asarray(p[name] * rng.uniform(0.9, 1.1, n))  # noqa: E731
    return jax.vmap(lambda k, c, s, t: model.set(K=k, C_f=c, S=s, t_c=t))(
        scale("K"), scale("C_f"), scale("S"), scale("t_c")
    )


def iterations_needed(batch, substeps):
    """Per member: the iterations its integration took (the index of its last new node), and
    whether it closes (reaches the closed phase)."""
    sims = jax.vmap(lambda m: vfjax.simulate(m, FPS, N, substeps=substeps, throw=False))(batch)
    t = np.asarray(sims.dense.t)
    need = np.argmax(t >= t[:, -1:], axis=1)
    return need, np.asarray(jnp.any(sims.phase == vfjax.phases.CLOSED, axis=1))


def iterations_budget(model):
    """Length of the node list minus the initial node: the scan's iteration count."""
    return jax.eval_shape(lambda m: vfjax.simulate(m, FPS, N), model).dense.t.shape[0] - 1


def best_time(fn, repeats):
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        times.append(time.perf_counter() - t0)
    return min(times)


def paired_times(fn, baseline, repeats):
    """Best times of ``fn`` and ``baseline``, timed alternately, so that a change of the
    machine's load during the run (a shared machine) moves both and not only the ratio."""
    t_fn, t_base = [], []
    for _ in range(repeats):
        t_base.append(best_time(baseline, 1))
        t_fn.append(best_time(fn, 1))
    return min(t_fn), min(t_base)


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--substeps", type=int, default=vfjax.DEFAULT_SUBSTEPS)
    args = ap.parse_args()
    from numba_reference import simulate_gaw

    model = vfjax.preset("N1")
    p = {k: float(v) for k, v in model.params().items()}
    numba_args = (p["K"], p["C_f"], p["S"], p["t_c"], p["P_s"], p["M"], p["l"], FPS, N)
    simulate_gaw(*numba_args, 128)  # compile
    n_rec = 20

    def numba_batch():
        return [simulate_gaw(*numba_args, 128) for _ in range(n_rec)]

    t_numba = best_time(numba_batch, args.repeats) / n_rec
    numba_rps = 1.0 / t_numba
    devices = jax.devices()
    print(f"machine: {os.cpu_count()} cores; jax {jax.__version__}, {len(devices)} CPU devices")
    print(
        f"numba scalar loop, k=128 (paper's step), 1 thread: {numba_rps:8.0f} recordings/s "
        f"({t_numba * 1e3:.2f} ms each)"
    )

    def batched(k):
        return jax.vmap(lambda m: vfjax.simulate(m, FPS, N, substeps=k, throw=False).area)

    def runner(k):
        return jax.jit(batched(k))

    mesh = Mesh(np.array(devices), ("batch",))
    split = NamedSharding(mesh, PartitionSpec("batch"))
    pool = ThreadPoolExecutor(len(devices))
    print(f"vfjax, default step k={args.substeps} (dt = 1/({args.substeps} fps)):")
    for b in (1, 64, 256):
        fn = runner(args.substeps)
        full = batch_of(model, b)
        cases = [("1 core", jax.device_put(full, devices[0]), fn)]
        if b % len(devices) == 0 and len(devices) > 1:
            # SPMD: one program, the batch sharded over the devices; `shard_map` runs the
            # simulator on each device's share as it is, so each share's loop stops when that
            # share is done (under plain sharding the loop's test would be a cross-device
            # reduction at every trip)
            mapped = jax.jit(
                jax.shard_map(
                    batched(args.substeps),
                    mesh=mesh,
                    in_specs=PartitionSpec("batch"),
                    out_specs=PartitionSpec("batch"),
                    check_vma=False,  # the loop's carries start from constants
                )
            )
            cases.append((f"{len(devices)} cores, shard_map", jax.device_put(full, split), mapped))
            # one thread per device, each running the same program on its share of the batch
            share = b // len(devices)
            parts = [
                jax.device_put(
                    jax.tree.map(lambda a, i=i, n=share: a[i * n : (i + 1) * n], full), d
                )
                for i, d in enumerate(devices)
            ]

            def threaded(parts, fn=fn):
                return list(pool.map(lambda part: jax.block_until_ready(fn(part)), parts))

            cases.append((f"{len(devices)} cores, threads", parts, threaded))
        for label, batch, call in cases:
            t0 = time.perf_counter()
            jax.block_until_ready(call(batch))
            compile_s = time.perf_counter() - t0
            t, t_base = paired_times(
                lambda call=call, batch=batch: call(batch), numba_batch, args.repeats
            )
            t_numba = min(t_numba, t_base / n_rec)
            print(
                f"  batch {b:4d}, {label:18s}: {b / t:8.0f} recordings/s "
                f"({b / t * t_base / n_rec:5.1f}x numba timed alongside: "
                f"{n_rec / t_base:.0f}/s)   first run {compile_s:.2f} s"
            )

    print("iterations each member needs (the loop runs as long as the batch's slowest member;")
    print(f"  the scan that derivatives go through runs them all: {iterations_budget(model)}):")
    for name in ("N1", "N2", "N3", "N4"):
        need, closes = iterations_needed(batch_of(vfjax.preset(name), 64), args.substeps)
        print(
            f"  batch of 64 around {name}: max {need.max()}, median {int(np.median(need))}, "
            f"min {need.min()}; {int((~closes).sum())} of 64 never close"
        )

    steps = (N - 1) * 128
    print("equal step k=128 (particle-steps per second; one step = one RK4 step of one model):")
    print(f"  numba, 1 thread: {steps / t_numba:12.3e}")
    for b in (64, 256):
        batch = jax.device_put(batch_of(model, b), devices[0])
        fn = runner(128)
        jax.block_until_ready(fn(batch))
        t = best_time(lambda fn=fn, batch=batch: fn(batch), max(1, args.repeats // 2))
        rate = b * steps / t
        print(f"  vfjax batch {b:3d}, 1 core: {rate:12.3e}  ({rate / (steps / t_numba):.2f}x)")


if __name__ == "__main__":
    main()
