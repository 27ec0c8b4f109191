"""Compiled programs kept across processes: traced once per machine, not once per process.

JAX's persistent compilation cache keeps a program's compiled executable, but every process
still traces and lowers the program's Python function before it can look it up: for the
fits' and the diagnosis's large programs, which simulate in several places, that is most of a
warm command's time. A function decorated with `program` is, on its first call for a
signature, exported (`jax.export`: its StableHLO) into the compilation cache's folder, and a
later process with the same signature deserialises it and calls it without tracing it. The
module is the one that tracing would lower, so XLA compiles (or loads from its own cache) the
same executable, which computes the same bits.

A signature is everything that shapes the program: the function, the shapes, dtypes and weak
types of its array arguments, the tree and values of every other argument (static), the
versions of vfjax's source (a hash of its files), JAX, jaxlib, equinox, lineax and
optimistix, and the JAX settings that change a lowering. A call runs as a plain
`equinox.filter_jit` where JAX's persistent compilation cache is off; where an argument holds
a class or function from outside vfjax and those libraries (a term of the user's own, whose
code can change under the same name), a device mesh or any other value without a text that
names it alike in every process; inside a transformation (`jax.vmap`, `jax.jit`); and where
a program cannot be exported (an output tree of custom nodes: the decorated functions return
tuples, named tuples marked `returned` and arrays).
"""

import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import pathlib
import re
import sys
import tempfile
import threading
import time

import equinox as eqx
import jax

#: The folder beside JAX's compilation cache that holds the exported programs.
FOLDER = "vfjax-programs"
#: Most bytes of exported programs kept; past it the oldest files are removed.
MAX_BYTES = 256 * 1024**2
_FORMAT = "1"  # the store's layout: a new value makes every stored program a miss
_PACKAGES = ("jax", "jaxlib", "equinox", "lineax", "optimistix")
#: The JAX settings that change a program's lowering.
_SETTINGS = (
    "jax_enable_x64",
    "jax_default_matmul_precision",
    "jax_numpy_dtype_promotion",
    "jax_numpy_rank_promotion",
    "jax_default_prng_impl",
    "jax_threefry_partitionable",
    "jax_enable_checks",
    "jax_debug_nans",
    "jax_debug_infs",
)


@functools.cache
def _versions() -> str:
    """The versions of vfjax's source (a hash of its files) and of the libraries it lowers
    through."""
    digest = hashlib.sha256()
    root = pathlib.Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    found = []
    for name in _PACKAGES:
        try:
            found.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            found.append(f"{name}=?")
    return digest.hexdigest() + ";" + ";".join(found)


def _store() -> pathlib.Path | None:
    """The folder of exported programs: beside JAX's persistent compilation cache where that
    is on, else None."""
    folder = jax.config.jax_compilation_cache_dir
    if not (jax.config.jax_enable_compilation_cache and folder):
        return None
    try:
        import flatbuffers  # noqa: F401  (jax.export's serialisation needs it)
    except ImportError:
        return None
    return pathlib.Path(folder) / FOLDER


#: The modules whose classes and functions a signature names: their code is covered by the
#: versions in it (`_versions`); a call holding anything from elsewhere (a term defined in a
#: notebook, which can change between processes under the same name) is not stored.
_KNOWN = ("vfjax", "jax", "jaxlib", "equinox", "lineax", "optimistix", "numpy", "builtins")


class _Unstable(Exception):
    """A value that has no text naming it the same way in every process."""


def _named(obj) -> str:
    """``module.qualname`` of a class or function of a `_KNOWN` module that is reachable
    under that name."""
    module, name = getattr(obj, "__module__", None), getattr(obj, "__qualname__", "")
    if not module or module.split(".")[0] not in _KNOWN or "<" in name:
        raise _Unstable(obj)
    found = sys.modules.get(module)
    for part in name.split("."):
        found = getattr(found, part, None)
    if found is not obj:
        raise _Unstable(obj)
    return f"{module}.{name}"


def _describe(x, out: list) -> None:
    """Append to ``out`` a text that determines ``x``'s part of a program: an array's dtype,
    shape and weak type; everything else by type and value (eqx Modules and named tuples
    field by field)."""
    if eqx.is_array(x):
        out.append(f"A{x.dtype}{list(x.shape)}{'w' if _weak(x) else ''}")
    elif x is None or isinstance(x, (bool, int, float, complex, str, bytes)):
        out.append(f"{type(x).__name__}:{x!r}")
    elif isinstance(x, eqx.Module) or hasattr(x, "_fields") and isinstance(x, tuple):
        fields = x._fields if isinstance(x, tuple) else [f.name for f in dataclasses.fields(x)]
        out.append(f"{_named(type(x))}({len(fields)})")
        for name in fields:
            out.append(name)
            _describe(getattr(x, name), out)
    elif isinstance(x, (tuple, list)):  # named tuples are described above
        out.append(f"{type(x).__name__}[{len(x)}]")
        for item in x:
            _describe(item, out)
    elif isinstance(x, dict):
        out.append(f"dict[{len(x)}]")
        for k in sorted(x, key=repr):
            _describe(k, out)
            _describe(x[k], out)
    elif isinstance(x, type) or callable(x) and hasattr(x, "__qualname__"):
        out.append(f"named:{_named(x)}")
    elif isinstance(x, enum.Enum):
        out.append(f"{_named(type(x))}.{x.name}")
    else:
        raise _Unstable(x)


def _signature(fn, args, kwargs) -> str | None:
    """The text that names the program of a call of ``fn``, or None where an argument has
    no text that names it the same way in every process (or holds a device mesh)."""
    parts = [
        _FORMAT,
        _versions(),
        f"{fn.__module__}.{fn.__qualname__}",
        f"platform={jax.default_backend()}",
        ";".join(f"{n}={getattr(jax.config, n)!r}" for n in _SETTINGS),
    ]
    try:
        _describe((args, kwargs), parts)
    except _Unstable:
        return None
    return "\n".join(parts)


def _weak(x) -> bool:
    return bool(getattr(x, "weak_type", False))


def _export(fn, in_tree, static, leaves):
    """``fn`` as a `jax.export.Exported` of its array leaves, every custom call allowed
    (the store is keyed by the exact jaxlib that runs them)."""

    def flat(*arrays):
        args, kwargs = eqx.combine(jax.tree.unflatten(in_tree, arrays), static)
        return fn(*args, **kwargs)

    flat.__name__, flat.__qualname__ = fn.__name__, fn.__qualname__  # as logs name it
    # one jitted function for both: the export reuses the lowering's trace
    jitted = jax.jit(flat)
    text = jitted.lower(*leaves).as_text()
    targets = sorted(set(re.findall(r"custom_call @([A-Za-z0-9_.]+)", text)))
    checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in targets]
    return jax.export.export(jitted, disabled_checks=checks)(*leaves)


def _write(path: pathlib.Path, data: bytes) -> None:
    """``data`` into ``path`` atomically (a temporary file renamed into place), then the
    oldest files removed past `MAX_BYTES`."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".partial-")
    try:
        with os.fdopen(fd, "wb") as out:
            out.write(data)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    for stale in path.parent.glob(".partial-*"):  # a writer killed mid-write
        try:
            if time.time() - stale.stat().st_mtime > 3600:
                stale.unlink()
        except OSError:
            pass
    files = sorted(
        (p for p in path.parent.glob("*.hlo") if p.is_file()), key=lambda p: p.stat().st_mtime
    )
    total = sum(p.stat().st_size for p in files)
    for old in files[:-1]:
        if total <= MAX_BYTES:
            break
        total -= old.stat().st_size
        old.unlink(missing_ok=True)


def returned(cls):
    """Class decorator: a `typing.NamedTuple` that a `program` returns, registered with
    `jax.export` under its module and name (no code is stored: the fields' names)."""
    name = f"{cls.__module__}.{cls.__name__}"
    jax.export.register_namedtuple_serialization(cls, serialized_name=name)
    return cls


def program(fn):
    """``fn`` compiled as `equinox.filter_jit` does (arrays traced, every other argument
    static), its exported program kept beside JAX's persistent compilation cache (see the
    module) so that a later process calls it without tracing. ``fn`` returns arrays in
    tuples, lists or dicts."""
    jitted = eqx.filter_jit(fn)
    loaded: dict = {}  # signature -> the jitted call of its exported program
    lock = threading.Lock()

    @functools.wraps(fn)
    def call(*args, **kwargs):
        folder = _store()
        if folder is None:
            return jitted(*args, **kwargs)
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, in_tree = jax.tree.flatten(dynamic)
        # inside a transformation (vmap, jit, jvp) the program is part of the caller's trace
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return jitted(*args, **kwargs)
        signature = _signature(fn, args, kwargs)
        if signature is None:
            return jitted(*args, **kwargs)
        with lock:
            run = loaded.get(signature)
            if run is None:
                run = _load(fn, folder, signature, in_tree, static, leaves)
                loaded[signature] = run
        if run is False:
            return jitted(*args, **kwargs)
        return run(*leaves)

    return call


def _load(fn, folder, signature, in_tree, static, leaves):
    """The jitted call of the stored program of ``signature`` (exported and stored first if
    absent), or False where it cannot be exported."""
    path = folder / f"{fn.__name__}-{hashlib.sha256(signature.encode()).hexdigest()}.hlo"
    try:
        exported = jax.export.deserialize(bytearray(path.read_bytes()))
    except Exception:  # absent, damaged or from another writer: exported below
        exported = None
    if exported is None:
        try:
            exported = _export(fn, in_tree, static, leaves)
            data = exported.serialize()
        except (ValueError, TypeError, NotImplementedError):
            return False  # an output of custom pytree nodes: not serialisable
        try:
            _write(path, bytes(data))
        except OSError:
            pass  # an unwritable folder: this process still runs the exported program

    def run(*arrays):
        return exported.call(*arrays)

    # as logs name it: the program's name, marked as stored
    run.__name__ = run.__qualname__ = f"{fn.__name__}_stored"
    return jax.jit(run)
