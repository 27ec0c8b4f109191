"""The stored programs (`vfjax._programs`): a later process calls a fit's programs without
tracing them, and they compute the bits that tracing them computes."""

import json
import os
import subprocess
import sys
import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import vfjax
from vfjax import _programs

#: A fresh process fits a small N3 recording with the compilation cache (and so the program
#: store) in the folder given as argv[1] ("off": no cache), and prints its numbers and the
#: functions JAX traced (as JSON).
_FIT = textwrap.dedent(
    """
    import json, sys
    import jax
    from jax import monitoring
    traced = set()
    def listen(event, seconds, **kw):
        if event.endswith("jaxpr_trace_duration"):
            traced.add(kw.get("fun_name"))
    monitoring.register_event_duration_secs_listener(listen)
    import numpy as np
    import vfjax
    from vfjax._runtime import use_compilation_cache
    if sys.argv[1] == "off":
        jax.config.update("jax_enable_compilation_cache", False)
    else:
        use_compilation_cache(sys.argv[1])
    truth = vfjax.preset("N3")
    sim = vfjax.simulate(truth, 4000.0, 150, t_start=0.0277)
    rec = vfjax.Recording(np.clip(np.asarray(sim.area), 0, None), 4000.0, name="n3")
    start = truth.set(K=1.2 * float(truth.params()["K"]), S=30.0)
    result = vfjax.fit(
        start, rec, swarm=vfjax.Swarm(size=8, iterations=4, chunk=4),
        polish=vfjax.Polish(max_steps=3), progress=False,
    )
    print(json.dumps({
        "nmse": result.nmse, "params": result.params, "shift": result.time_shift,
        "pso": result.pso_trace, "traced": sorted(n for n in traced if n),
    }))
    """
)

_PROGRAMS = ("_swarm_chunk", "_polish_batch")


def _fit_in_a_process(tmp_path, cache) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("JAX_COMPILATION_CACHE")}
    env["JAX_PLATFORMS"] = "cpu"
    run = subprocess.run(
        [sys.executable, "-c", _FIT, str(cache)],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        timeout=600,
        env=env,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    return json.loads(run.stdout.strip().splitlines()[-1])


def test_a_later_process_calls_the_fit_without_tracing_it_and_gets_the_same_bits(tmp_path):
    """Three fresh processes fit one recording: the first with an empty cache folder traces
    the fit's swarm and polish and stores them; the second, with that folder, traces
    neither and computes every number bit for bit as the first; the third, with the cache
    off, traces them as `equinox.filter_jit` and computes the same bits again."""
    cache = tmp_path / "cache"
    first = _fit_in_a_process(tmp_path, cache)
    stored = sorted(p.name.split("-")[0] for p in (cache / _programs.FOLDER).glob("*.hlo"))
    assert set(_PROGRAMS) <= set(stored), stored
    assert set(_PROGRAMS) <= set(first["traced"]), first["traced"]
    second = _fit_in_a_process(tmp_path, cache)
    assert not set(_PROGRAMS) & set(second["traced"]), second["traced"]
    plain = _fit_in_a_process(tmp_path, "off")
    assert set(_PROGRAMS) <= set(plain["traced"])
    assert not list((tmp_path / "off").glob("*"))
    for other in (second, plain):
        assert {k: v for k, v in other.items() if k != "traced"} == {
            k: v for k, v in first.items() if k != "traced"
        }
    assert 0 < first["nmse"] < 0.05  # a fit, not a failure, was compared


@_programs.program
def _scaled(x, factor: float, power: int):
    return (x * factor) ** power, jnp.sum(x)


class _Local(eqx.Module):  # a class the store cannot name across processes (a test's)
    weight: float


def test_the_signature_names_everything_that_shapes_the_program():
    """Arrays by dtype, shape and weak type; other arguments by value, eqx Modules and named
    tuples field by field; a class of a module outside vfjax and its libraries (a notebook's
    term, which can change under the same name) and a device mesh are not stored."""
    fn = _scaled.__wrapped__
    x = np.arange(3.0)

    def sig(*args, **kwargs):
        return _programs._signature(fn, args, kwargs)

    base = sig(x, 2.0, 3)
    assert base is not None and base == sig(x + 1.0, 2.0, 3)  # values of arrays are data
    different = [
        sig(x, 2.5, 3),
        sig(x, 2.0, 4),
        sig(np.arange(4.0), 2.0, 3),
        sig(np.arange(3, dtype=np.float32), 2.0, 3),
        sig(x, 2, 3),  # an int is not a float
    ]
    assert all(s is not None for s in different)
    assert len({base, *different}) == len(different) + 1
    weak, strong = jnp.asarray(2.0), jnp.asarray(2.0, dtype=jnp.float64)
    assert weak.weak_type and not strong.weak_type and sig(weak, 2.0, 3) != sig(strong, 2.0, 3)
    swarm = vfjax.Swarm()
    assert sig(x, swarm, 3) != sig(x, vfjax.Swarm(size=12), 3)
    assert sig(x, vfjax.Polish(), 3) is not None  # optimistix's solver and its norm function
    assert sig(x, _Local(1.0), 3) is None
    mesh = jax.sharding.Mesh(np.array(jax.devices()[:1]), ("a",))
    assert sig(x, mesh, 3) is None
    assert sig(x, lambda y: y, 3) is None


def test_a_damaged_or_unwritable_store_still_computes(tmp_path):
    """A stored file that cannot be read is exported again; a store that cannot be written
    (a file in the folder's place) leaves the call its program in this process; the values
    are those of the function."""
    folder = tmp_path / "cache"
    previous = (jax.config.jax_compilation_cache_dir, jax.config.jax_enable_compilation_cache)

    @_programs.program
    def cubic(x, offset: float):
        return (x**3 + offset,)

    x = np.linspace(0.0, 1.0, 5)
    try:
        jax.config.update("jax_compilation_cache_dir", str(folder))
        jax.config.update("jax_enable_compilation_cache", True)
        (first,) = cubic(x, 0.5)
        (path,) = (folder / _programs.FOLDER).glob("cubic-*.hlo")
        path.write_bytes(b"not a program")

        @_programs.program
        def cubic(x, offset: float):  # the same function in a new process's memory
            return (x**3 + offset,)

        (again,) = cubic(x, 0.5)
        assert path.read_bytes() != b"not a program"
        # a file where the store's folder should be: nothing can be read or written there
        jax.config.update("jax_compilation_cache_dir", str(tmp_path / "other"))
        (tmp_path / "other").mkdir()
        (tmp_path / "other" / _programs.FOLDER).write_text("")

        @_programs.program
        def cubic(x, offset: float):
            return (x**3 + offset,)

        (unwritten,) = cubic(x, 0.5)
    finally:
        jax.config.update("jax_compilation_cache_dir", previous[0])
        jax.config.update("jax_enable_compilation_cache", previous[1])
    for y in (first, again, unwritten):
        np.testing.assert_allclose(np.asarray(y), x**3 + 0.5, rtol=1e-15)


def test_a_program_under_a_transformation_is_traced_with_it():
    """Inside `jax.vmap` or `jax.jit` a program is part of the caller's trace (a stored
    program has no batching rule), and gives the function's values there."""
    x = jnp.arange(6.0).reshape(2, 3)
    batched = jax.vmap(lambda row: _scaled(row, 2.0, 2))(x)
    np.testing.assert_allclose(np.asarray(batched[0]), (2.0 * np.asarray(x)) ** 2)
    inside = jax.jit(lambda row: _scaled(row, 3.0, 1)[1])(x[1])
    assert float(inside) == pytest.approx(12.0)


def test_kept_programs_are_released_past_the_memory_maps_budget(monkeypatch):
    """Compiled programs stay in memory while the process's memory maps are under the
    budget; past it the least recently used are released (their maps unmapped), and a
    released program called again computes the same values."""
    _programs.KEPT.clear()

    @_programs.program(store=False)
    def waves(x, k: int):
        def body(i, y):
            return jnp.sin(k * y) + jnp.cos(y * i) * jnp.exp(-y) + jnp.sort(y) ** 2

        y = jax.lax.fori_loop(0, 5, body, x)
        return jnp.cumsum(y), jnp.tanh(y).sum()

    x = np.linspace(0.0, 1.0, 64)
    # an unlimited budget: every program is kept, each with memory maps of its own
    monkeypatch.setattr(_programs, "_map_limit", lambda: 10**9)
    before = _programs._map_count()
    first = [waves(x, k) for k in range(8)]
    kept = _programs._map_count()
    assert len(_programs.KEPT) == 8 and kept - before >= 8
    # a budget a little above what the process holds without them: the oldest go first
    budget = before + (kept - before) // 4
    monkeypatch.setattr(_programs, "_map_limit", lambda: budget / _programs.MAP_SHARE)
    again = waves(x, 8)
    assert 1 <= len(_programs.KEPT) < 8
    assert _programs._map_count() <= budget or len(_programs.KEPT) == 1
    assert _programs._map_count() < kept  # released programs are unmapped
    # the newest is kept; a released one compiles again and computes the same values
    for k in (8, 0, 1):
        values = waves(x, k)
        expected = again if k == 8 else first[k]
        for a, b in zip(values, expected):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    # with no way to count the maps, at most MAX_PROGRAMS are kept
    monkeypatch.setattr(_programs, "_map_limit", lambda: None)
    monkeypatch.setattr(_programs, "MAX_PROGRAMS", 3)
    for k in range(10, 15):
        waves(x, k)
    assert len(_programs.KEPT) == 3
    _programs.KEPT.clear()
