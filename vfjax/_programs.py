"""Compiled programs: traced once per machine, not once per process, and kept in memory
within a bound.

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
optimistix, and the JAX settings that change a lowering. A call's program is traced as
`equinox.filter_jit` traces it, not stored, where JAX's persistent compilation cache is off;
where an argument holds a class or function from outside vfjax and those libraries (a term
of the user's own, whose code can change under the same name), a device mesh or any other
value without a text that names it alike in every process; where the decorator says
``store=False``; and where a program cannot be exported (an output tree of custom nodes).

Either way the compiled program is kept in this process's `KEPT` programs, which release the
least recently used past a budget of memory maps (`_Kept`): a process that compiles the
programs of one model structure after another (a cohort, a notebook trying effects) holds a
bounded number of them, where JAX's own caches would keep every one. Inside a
transformation (`jax.vmap`, `jax.jit`) a decorated function is part of the caller's trace.
"""

import collections
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
#: Share of the kernel's limit on a process's memory maps up to which compiled programs are
#: kept in memory (`KEPT`).
MAP_SHARE = 0.5
#: Most compiled programs kept in memory where the process's memory maps cannot be counted.
MAX_PROGRAMS = 64
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


class _Kept:
    """The compiled programs this process keeps in memory, least recently used released
    first.

    Each compiled program holds memory maps of its machine code (XLA's CPU executables map
    their kernels page by page: a fit's programs some 1 400, a diagnosis's 9 000-17 000 a
    model structure), and Linux refuses a process more than ``vm.max_map_count`` of them
    (65 530 by default), where XLA's compiler crashes. So the programs are kept while the
    process's maps stay under `MAP_SHARE` of that limit; past it the least recently used
    are released (a later call compiles the program again, or loads it from the persistent
    compilation cache). Where the maps cannot be counted (no ``/proc``), at most
    `MAX_PROGRAMS` are kept."""

    def __init__(self):
        self._programs: collections.OrderedDict = collections.OrderedDict()
        self._lock = threading.Lock()

    def get(self, key):
        with self._lock:
            found = self._programs.get(key)
            if found is not None:
                self._programs.move_to_end(key)
            return found

    def put(self, key, compiled) -> None:
        with self._lock:
            self._programs[key] = compiled
            self._programs.move_to_end(key)
            limit = _map_limit()
            if limit is None:
                while len(self._programs) > MAX_PROGRAMS:
                    self._programs.popitem(last=False)
                return
            budget = int(MAP_SHARE * limit)
            # the newest stays: its caller runs it next
            while len(self._programs) > 1 and _map_count() > budget:
                self._programs.popitem(last=False)

    def __len__(self) -> int:
        return len(self._programs)

    def clear(self) -> None:
        with self._lock:
            self._programs.clear()


def _map_count() -> int:
    """How many memory maps this process holds (Linux)."""
    with open("/proc/self/maps", "rb") as maps:
        return sum(1 for _ in maps)


@functools.cache
def _map_limit() -> int | None:
    """The kernel's limit on a process's memory maps, or None where it cannot be read (no
    ``/proc``: not Linux)."""
    try:
        limit = int(pathlib.Path("/proc/sys/vm/max_map_count").read_text())
        _map_count()
    except (OSError, ValueError):
        return None
    return limit


#: The compiled programs of this process (`_Kept`).
KEPT = _Kept()


def _key(call, in_tree, static, leaves):
    """What names a compiled program within this process: the decorated function, the
    trees, the static values (with their types: ``1`` and ``True`` are other programs) and
    each array's dtype, shape, weak type and placement; None where a static value cannot be
    hashed."""
    static_leaves, static_tree = jax.tree.flatten(static)
    key = (
        call,
        in_tree,
        static_tree,
        tuple((type(x), x) for x in static_leaves),
        tuple(
            (x.dtype, x.shape, _weak(x), getattr(x, "sharding", None) if _committed(x) else None)
            for x in leaves
        ),
    )
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _committed(x) -> bool:
    return bool(getattr(x, "committed", False))


def program(fn=None, *, store: bool = True):
    """``fn`` compiled as `equinox.filter_jit` does (arrays traced, every other argument
    static) and kept in this process's `KEPT` programs (released past the memory maps'
    budget). With ``store``, its exported program is also kept beside JAX's persistent
    compilation cache (see the module) so that a later process calls it without tracing;
    ``fn`` then returns arrays in tuples, lists, dicts or named tuples marked `returned`
    (``store=False`` for any other output, which cannot be exported)."""
    if fn is None:
        return functools.partial(program, store=store)
    jitted = eqx.filter_jit(fn)
    unexported: set = set()  # signatures whose program cannot be exported
    lock = threading.Lock()

    @functools.wraps(fn)
    def call(*args, **kwargs):
        dynamic, static = eqx.partition((args, kwargs), eqx.is_array)
        leaves, in_tree = jax.tree.flatten(dynamic)
        # inside a transformation (vmap, jit, jvp) the program is part of the caller's trace
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return jitted(*args, **kwargs)
        key = _key(call, in_tree, static, leaves)
        if key is None:
            return jitted(*args, **kwargs)
        compiled = KEPT.get(key)
        if compiled is None:
            with lock:  # one compilation of a program at a time
                compiled = KEPT.get(key)
                if compiled is None:
                    compiled = _compile(
                        fn, store, unexported, args, kwargs, in_tree, static, leaves
                    )
                    KEPT.put(key, compiled)
        return compiled(*leaves)

    return call


def _compile(fn, store, unexported, args, kwargs, in_tree, static, leaves):
    """The compiled program of a call: of its stored program where ``store`` and the store
    is on (exported and stored first if absent), else of ``fn`` traced."""
    folder = _store() if store else None
    signature = None if folder is None else _signature(fn, args, kwargs)
    exported = None
    if signature is not None and signature not in unexported:
        exported = _load(fn, folder, signature, in_tree, static, leaves)
        if exported is None:
            unexported.add(signature)
    if exported is None:

        def run(*arrays):
            args, kwargs = eqx.combine(jax.tree.unflatten(in_tree, arrays), static)
            return fn(*args, **kwargs)

        name = fn.__name__  # as logs name it
    else:

        def run(*arrays):
            return exported.call(*arrays)

        name = f"{fn.__name__}_stored"  # as logs name it: the program's name, marked as stored
    run.__name__ = run.__qualname__ = name
    return jax.jit(run).lower(*leaves).compile()


def _load(fn, folder, signature, in_tree, static, leaves):
    """The stored program of ``signature`` (`jax.export.Exported`; exported and stored
    first if absent), or None where it cannot be exported."""
    path = folder / f"{fn.__name__}-{hashlib.sha256(signature.encode()).hexdigest()}.hlo"
    try:
        return jax.export.deserialize(bytearray(path.read_bytes()))
    except Exception:  # absent, damaged or from another writer: exported below
        pass
    try:
        exported = _export(fn, in_tree, static, leaves)
        data = exported.serialize()
    except (ValueError, TypeError, NotImplementedError):
        return None  # an output of custom pytree nodes: not serialisable
    try:
        _write(path, bytes(data))
    except OSError:
        pass  # an unwritable folder: this process still runs the exported program
    return exported
