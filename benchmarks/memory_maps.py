"""One process that fits and diagnoses one model structure after another: the memory maps
it holds after each (Linux's limit on a process is ``vm.max_map_count``, 65 530 by default,
where XLA's compiler crashes), their peak (sampled every 0.2 s) and the compiled programs
vfjax keeps (`vfjax._programs.KEPT`, released past half the limit).

The recording is vfjax's demo (N3, 2 px noise); each structure is the paper's model from
`vfjax.initial_model` with one catalogue effect added (the first none), fitted with
`vfjax.fit` and diagnosed with `vfjax.diagnose` at the default settings, so each diagnosis
compiles the programs of its structure and of that structure with each candidate. The
last structure repeats the second, whose programs are then among the least recently used.
Linux only (it reads ``/proc/self/maps``).

Run: python benchmarks/memory_maps.py [--structures N] [--cache-dir DIR]
"""

import argparse
import tempfile
import threading
import time

import vfjax
from vfjax import _programs
from vfjax.cli import use_compilation_cache

EFFECTS = (
    None,
    vfjax.GlottalGap(a_gap=0.01),
    vfjax.MucosalDelay(tau=2e-4),
    vfjax.CubicStiffness(),
    vfjax.SourceTractInertance(I_t=0.01),
    vfjax.PowerLawTissue(eta_pl=0.1),
    vfjax.PressureModulation(a_pm=0.05),
    vfjax.LeftRightAsymmetry(Q=1.1),
    vfjax.GlottalGap(a_gap=0.01),
)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--structures", type=int, default=len(EFFECTS))
    parser.add_argument("--cache-dir", help="compilation cache folder (default: a new empty one)")
    args = parser.parse_args()
    use_compilation_cache(args.cache_dir or tempfile.mkdtemp(prefix="vfjax-maps-"))
    peak = [0]

    def sample():
        while True:
            peak[0] = max(peak[0], _programs._map_count())
            time.sleep(0.2)

    threading.Thread(target=sample, daemon=True).start()
    limit = _programs._map_limit()
    print(f"limit {limit} maps, programs kept up to {_programs.MAP_SHARE * limit:.0f}")
    print(f"start: {_programs._map_count()} maps")
    print("| structure | maps after | peak so far | programs kept | wall (s) | verdict |")
    print("|---|---|---|---|---|---|")
    rec = vfjax.datasets.demo_recording()
    start = vfjax.initial_model(rec)
    for effect in EFFECTS[: args.structures]:
        model = start if effect is None else start.with_effect(effect)
        began = time.perf_counter()
        diagnosis = vfjax.diagnose(vfjax.fit(model, rec, progress=False), rec, progress=False)
        name = "paper's model" if effect is None else f"+ {type(effect).__name__}"
        print(
            f"| {name} | {_programs._map_count()} | {peak[0]} | {len(_programs.KEPT)} | "
            f"{time.perf_counter() - began:.0f} | {diagnosis.verdict.split('(')[0].strip()} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
