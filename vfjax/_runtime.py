"""How a vfjax process runs JAX: its persistent compilation cache and its CPU devices (the
command line's and a cohort's workers' settings)."""

import os
import pathlib
import sys


def cache_folder() -> pathlib.Path:
    """Where the command line keeps JAX's persistent compilation cache: ``$VFJAX_CACHE_DIR``,
    else ``vfjax/jax`` in the user's cache folder (``$XDG_CACHE_HOME``, else ``~/.cache``)."""
    if os.environ.get("VFJAX_CACHE_DIR"):
        return pathlib.Path(os.environ["VFJAX_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or pathlib.Path.home() / ".cache"
    return pathlib.Path(base) / "vfjax" / "jax"


#: Most bytes the command line's compilation cache holds; past it the programs used least
#: recently are removed. A bounded cache also makes JAX lock the folder for every read and
#: write, so processes running side by side never read a program half written.
CACHE_MAX_BYTES = 2 * 1024**3
#: Programs that compile faster than this (s) are not cached. Every program is: a diagnosis
#: also compiles some two hundred small ones (array operations between its large programs),
#: and a later process loads them faster than it compiles them (a warm `vfjax diagnose` of
#: the shared syn_base, benchmarks/README.md).
CACHE_MIN_COMPILE_S = 0.0


def use_compilation_cache(folder=None) -> pathlib.Path | None:
    """Turn on JAX's persistent compilation cache in ``folder`` (default `cache_folder`), so
    that a program compiled once (a fit of a model structure) is loaded, not compiled again,
    by later processes, up to `CACHE_MAX_BYTES`. A folder that cannot be written leaves the
    cache off, with one warning on stderr. Returns the folder in use, or None."""
    import tempfile

    import jax

    folder = pathlib.Path(folder) if folder is not None else cache_folder()
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".probe-"):
            pass
    except OSError as err:
        reason = err.strerror or err
        print(
            f"vfjax: warning: compilation cache off: cannot write {folder} ({reason})",
            file=sys.stderr,
        )
        return None
    jax.config.update("jax_compilation_cache_dir", str(folder))
    jax.config.update("jax_compilation_cache_max_size", CACHE_MAX_BYTES)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", CACHE_MIN_COMPILE_S)
    return folder


def use_cpu_cores(cores: int | None = None) -> int:
    """Give JAX's CPU backend one device per core (``cores``, default every core of the
    machine), so that the fits split their batches into as many groups, computed side by
    side in threads of their own (through one compiled copy of each program: see
    `vfjax.fit_many`). Must run before JAX computes anything; afterwards it changes nothing
    and returns the devices JAX has."""
    import jax

    cores = (os.cpu_count() or 1) if cores is None else int(cores)
    if cores < 1:
        raise ValueError(f"cores must be >= 1, got {cores}")
    try:
        jax.config.update("jax_num_cpu_devices", cores)
    except RuntimeError:  # the backend is already running
        return len(jax.devices())
    return cores
