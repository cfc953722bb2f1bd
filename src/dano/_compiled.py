"""Compiled once per structure, across processes: jitted functions whose traced programs are
kept on disk.

JAX's persistent compilation cache (:func:`dano.enable_compilation_cache`) saves XLA's
compile, but every new process still traces and lowers each function again, and for an
MJX rollout under ``vmap`` and ``jacfwd`` that is most of the wait (the soap's residual and
Jacobian: 6.3 s of tracing and lowering, 0.5 s to load the compiled program from the
cache). :func:`cached_jit` wraps a function like ``jax.jit`` and, with the cache on, keeps
each traced and lowered program (a :class:`jax.export.Exported`, StableHLO) in
``<cache>/dano-exported/``, keyed on everything that decides the trace:

* the function (module and name) and a digest of dano's own source files;
* the versions of jax, jaxlib, mujoco and mujoco-mjx, the backend, 64-bit mode, XLA_FLAGS;
* the static arguments and the structure of the others: their pytree definitions with
  all static metadata by content (MuJoCo models as their binary MJB, contact models,
  layouts; an object it cannot digest by content makes the call a plain ``jax.jit`` call;
  dataclass fields marked ``metadata={"cache_key": False}`` are left out), and every leaf's
  shape, dtype and weak type.

Values are arguments, never part of the key: problems of the same structure (other
observations, parameters, initial states, other objects with as many samples) load the
program instead of tracing it again. Fields marked :data:`HOST_ONLY` (a scene's MuJoCo C
model and assets, its name, an asset's provenance: host-side facts that vary from object to
object) are left out of the key and hidden from the trace: a program traced for export
sees them as a placeholder that raises :class:`TracedHostOnlyError` when read, so a trace
cannot bake in what its key does not hold. Fields marked only ``{"cache_key": False}`` are
read by the trace, and something else in the key stands for them (a trajectory
optimisation problem's ``key``, :mod:`dano.trajopt.ilqr`).

Sharded programs (``mesh=``: a function of the static arguments that returns the
:class:`jax.sharding.Mesh` the function's ``shard_map`` runs on, or None) are exported and
called with every argument and result replicated over that mesh (``in_shardings`` /
``out_shardings``; the program splits its batch inside and gathers its result), so a loaded
program runs on the same number of devices, across processes too; the static arguments
must tell the mesh's size (e.g. a layout's shard count), so that its key differs from the
single-device program's.
Single-device programs in a single process are called with every argument committed to one
device (across processes committing them hung the two-process identification), so that a
call on a program's own output (committed) beside fresh inputs runs the same executable
instead of lowering and compiling it again.
Called with tracers (inside ``jit``, ``vmap``, ``jacfwd``, ...) or with the cache off, a
cached function is plain ``jax.jit``, so it composes as usual. ``DANO_EXPORT_CACHE=0``
turns the disk part off.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import functools
import hashlib
import importlib.metadata
import os
import pickle
import threading
import time
import weakref
from pathlib import Path

import jax
import numpy as np

#: seconds spent in calls that traced, loaded or compiled a program (process-wide; callers
#: report their own share as the difference before and after)
COMPILE_SECONDS = [0.0]
#: how many programs were traced (and exported) and how many were loaded from disk
COUNTS = collections.Counter()


def shape_bucket(n: int, bits: int = 3) -> int:
    """``n`` rounded up to a shape that many sizes share, so that one compiled program serves
    them all (padded rows or steps are computed and dropped): ``n`` kept to its ``bits``
    leading binary digits, rounded up. bits = 3: ``n`` itself up to 8, then 9 → 10, 100 → 112,
    200 → 224 (at most 25 % more, 9 % on average); bits = 1: the next power of two (3 → 4,
    5 → 8). Raises ValueError for n < 0 or bits < 1."""
    if n < 0 or bits < 1:
        raise ValueError(f"shape_bucket: needs n >= 0 and bits >= 1, got n={n}, bits={bits}")
    step = 1 << max(0, n.bit_length() - bits)
    return -(-n // step) * step


#: dataclass field metadata of host-side facts that no traced program may read: left out of
#: the key, and a placeholder raising :class:`TracedHostOnlyError` in an exported trace
HOST_ONLY = {"cache_key": False, "traced": False}

_DIRECTORY: list[Path | None] = [None]
_FUNCTIONS: "weakref.WeakSet[CachedFunction]" = weakref.WeakSet()
_LOCK = threading.Lock()
#: held while a program is traced and exported (or loaded): one trace at a time. Tracing is
#: Python, under Python's lock, so two traces side by side both finish late; one after the
#: other, the first program compiles in XLA (without Python's lock) while the second traces
_TRACING = threading.RLock()
_MEMORY_SIZE = 64  # loaded programs kept per process (least recently used dropped first)


# ------------------------------------------------------------------ the compile clock

#: JAX's monitoring events of tracing, lowering and XLA compiling (a load from the persistent
#: compilation cache is reported as a compile)
_COMPILE_EVENTS = ("/jax/core/compile/jaxpr_trace_duration", "/jax/core/compile/jaxpr_to_mlir_module_duration",
                   "/jax/core/compile/backend_compile_duration")
_SPANS: list[tuple[float, float]] = []


def _record_span(event: str, start: float, end: float, **_) -> None:
    if event in _COMPILE_EVENTS:
        _SPANS.append((start, end))


jax.monitoring.register_event_time_span_listener(_record_span)


def compile_seconds(since: float = 0.0) -> float:
    """Seconds this process has spent tracing, lowering and compiling JAX programs (loads from
    the compilation caches included) since the time ``since`` (``time.time()``; default: ever),
    nested spans counted once (JAX's monitoring events). Every ``--json`` reports it as
    ``compile_time_s`` where a verb has no finer account of its own."""
    spans = sorted((max(a, since), b) for a, b in list(_SPANS) if b > since)
    total, reach = 0.0, -np.inf
    for a, b in spans:
        if b > reach:
            total += b - max(a, reach)
            reach = b
    return total


def set_directory(path: str | os.PathLike | None) -> None:
    """Keep exported programs in ``path`` instead of beside JAX's compilation cache (None:
    back to that default)."""
    _DIRECTORY[0] = None if path is None else Path(path)


def directory() -> Path | None:
    """Where exported programs are kept: :func:`set_directory`'s folder, else
    ``<JAX's compilation cache folder>/dano-exported`` when that cache is on
    (:func:`dano.enable_compilation_cache`, which the command line calls); None (traced in
    every process, as plain ``jax.jit``) when it is off or ``DANO_EXPORT_CACHE=0``."""
    if os.environ.get("DANO_EXPORT_CACHE", "1").lower() in ("0", "false", "no", "off"):
        return None
    if _DIRECTORY[0] is not None:
        return _DIRECTORY[0]
    jax_dir = jax.config.jax_compilation_cache_dir
    return Path(jax_dir) / "dano-exported" if jax_dir else None


class _Unkeyable(Exception):
    """An argument's static part cannot be digested by content."""


class TracedHostOnlyError(RuntimeError):
    """A traced program read a field marked :data:`HOST_ONLY` (a bug in dano: what the trace
    reads must be in the program's key)."""


class _HostOnly:
    """What a traced program sees of a :data:`HOST_ONLY` field: reading it raises."""

    __slots__ = ("_where",)

    def __init__(self, where: str):
        object.__setattr__(self, "_where", where)

    def _fail(self, *_, **__):
        raise TracedHostOnlyError(f"{object.__getattribute__(self, '_where')} is host-only (left out of the "
                                  "compiled program's key) but was read while tracing it")

    __getattr__ = __getitem__ = __iter__ = __len__ = __bool__ = __str__ = __format__ = __call__ = _fail
    __eq__ = __lt__ = __le__ = __gt__ = __ge__ = __contains__ = __index__ = __int__ = __float__ = _fail

    def __repr__(self) -> str:
        return f"<host-only {object.__getattribute__(self, '_where')}>"

    __hash__ = object.__hash__


def _hide_host_only(x, seen: dict | None = None):
    """``x`` with every :data:`HOST_ONLY` field of the dataclasses in it (through dataclass
    fields, tuples, lists and dicts) replaced by a :class:`_HostOnly` placeholder; what holds
    none is returned as it is."""
    seen = {} if seen is None else seen
    if id(x) in seen:
        return seen[id(x)]
    out = x
    if dataclasses.is_dataclass(x) and not isinstance(x, type):
        changes = {}
        for f in dataclasses.fields(x):
            if not hasattr(x, f.name):
                continue
            value = getattr(x, f.name)
            if f.metadata.get("traced") is False:
                changes[f.name] = _HostOnly(f"{type(x).__qualname__}.{f.name}")
            else:
                new = _hide_host_only(value, seen)
                if new is not value:
                    changes[f.name] = new
        if changes:
            out = _replace_fields(x, changes)
    elif isinstance(x, (tuple, list)) and type(x) in (tuple, list):
        items = [_hide_host_only(v, seen) for v in x]
        if any(a is not b for a, b in zip(items, x)):
            out = type(x)(items)
    elif type(x) is dict:
        items = {k: _hide_host_only(v, seen) for k, v in x.items()}
        if any(items[k] is not x[k] for k in x):
            out = items
    seen[id(x)] = out
    return out


def _replace_fields(x, changes: dict):
    """A shallow copy of dataclass ``x`` with ``changes`` set, without running its
    ``__init__`` or ``__post_init__`` (validation would read the placeholders)."""
    new = object.__new__(type(x))
    for f in dataclasses.fields(x):
        if hasattr(x, f.name):
            object.__setattr__(new, f.name, changes.get(f.name, getattr(x, f.name)))
    for k, v in getattr(x, "__dict__", {}).items():  # (attributes beyond the fields, e.g. caches)
        if k not in changes and not any(k == f.name for f in dataclasses.fields(x)):
            object.__setattr__(new, k, v)
    return new


@functools.lru_cache(maxsize=1)
def _environment() -> bytes:
    """What every key shares: dano's source digest, library versions, backend, flags."""
    h = hashlib.sha256()
    root = Path(__file__).resolve().parent
    for path in sorted(root.rglob("*.py")):
        h.update(str(path.relative_to(root)).encode())
        h.update(path.read_bytes())
    for dist in ("jax", "jaxlib", "mujoco", "mujoco-mjx"):
        try:
            h.update(f"{dist}={importlib.metadata.version(dist)};".encode())
        except importlib.metadata.PackageNotFoundError:  # pragma: no cover
            h.update(f"{dist}=none;".encode())
    h.update(os.environ.get("XLA_FLAGS", "").encode())
    return h.digest()


def _session() -> bytes:
    """The parts of the key that may change within a process."""
    devices = jax.devices()
    kinds = sorted({d.device_kind for d in devices})
    return (f"{jax.default_backend()};{kinds};{len(devices)} devices;{jax.process_count()} processes;"
            f"x64={jax.config.jax_enable_x64};").encode()


def _digest_value(x, h) -> None:
    """Feed a static value into hash ``h`` by content; raises _Unkeyable where it cannot."""
    if x is None or isinstance(x, (bool, int, float, complex, str, bytes)):
        h.update(f"{type(x).__name__}:{x!r};".encode())
    elif isinstance(x, enum.Enum):
        h.update(f"enum:{type(x).__module__}.{type(x).__qualname__}.{x.name};".encode())
    elif isinstance(x, type):
        h.update(f"type:{x.__module__}.{x.__qualname__};".encode())
    elif isinstance(x, (tuple, list, frozenset, set)):
        items = sorted(x, key=repr) if isinstance(x, (frozenset, set)) else x
        h.update(f"{type(x).__name__}[{len(items)}](".encode())
        for item in items:
            _digest_value(item, h)
        h.update(b")")
    elif isinstance(x, dict):
        h.update(f"dict[{len(x)}](".encode())
        for k in sorted(x, key=repr):
            _digest_value(k, h)
            _digest_value(x[k], h)
        h.update(b")")
    elif isinstance(x, (np.ndarray, np.generic, jax.Array)):
        a = np.ascontiguousarray(np.asarray(x))
        h.update(f"array:{a.dtype.str}{a.shape};".encode())
        h.update(a.tobytes() if a.dtype != object else repr(a.tolist()).encode())
    elif type(x).__name__ == "_NumPyArrayHashWrapper":  # MJX's static numpy fields
        _digest_value(x.array, h)
    elif type(x).__name__ == "MjModel" and type(x).__module__.startswith("mujoco"):
        import mujoco

        buffer = np.zeros(mujoco.mj_sizeModel(x), dtype=np.uint8)
        mujoco.mj_saveModel(x, None, buffer)
        h.update(b"MjModel:")
        h.update(hashlib.sha256(buffer.tobytes()).digest())
    elif dataclasses.is_dataclass(x):
        h.update(f"dataclass:{type(x).__module__}.{type(x).__qualname__}(".encode())
        for f in dataclasses.fields(x):
            if f.metadata.get("cache_key") is False:  # a label no trace reads (a name, provenance)
                continue
            h.update(f"{f.name}=".encode())
            _digest_value(getattr(x, f.name), h)
        h.update(b")")
    elif isinstance(x, jax.tree_util.PyTreeDef):
        _digest_tree(x, h)
    else:
        raise _Unkeyable(f"{type(x).__module__}.{type(x).__qualname__}")


def _digest_tree(tree, h) -> None:
    """A pytree definition with its static metadata, by content."""
    data = tree.node_data()
    if data is None:
        h.update(b"*")
        return
    kind, aux = data
    h.update(f"<{kind.__module__}.{kind.__qualname__}:".encode())
    _digest_value(aux, h)
    for child in tree.children():
        _digest_tree(child, h)
    h.update(b">")


def _aval(x):
    """(shape, dtype, weak type) of a leaf; arrays without JAX's abstract-value machinery."""
    if isinstance(x, np.ndarray):
        return (x.shape, x.dtype.str, False)
    if isinstance(x, jax.Array) and not isinstance(x, jax.core.Tracer):
        return (x.shape, x.dtype.str, bool(x.weak_type))
    aval = jax.typeof(x)
    return (tuple(aval.shape), np.dtype(aval.dtype).str, bool(getattr(aval, "weak_type", False)))


def _abstract(x):
    shape, dtype, weak = _aval(x)
    return jax.ShapeDtypeStruct(shape, np.dtype(dtype), weak_type=weak)


class CachedFunction:
    """A jitted function whose traced program is kept on disk per structure (see the module
    documentation). Call it like the function; ``lower`` and other ``jax.jit`` attributes
    are those of the jitted function a call would use: with the compiler options outside
    any JAX trace, the plain one (``.jit``) inside one."""

    def __init__(self, fn, static_argnums=(), mesh=None, compiler_options=None):
        self.fn = fn
        self.static_argnums = tuple(sorted(static_argnums))
        self._compiler_options = compiler_options
        self.jit = jax.jit(fn, static_argnums=self.static_argnums)
        self._top_jit = None  # self.jit with the compiler options (JAX takes them on a top-level call only)
        self.mesh_of = mesh
        self._sharded_jits: dict = {}  # mesh -> jax.jit with replicated in/out shardings
        self.name = f"{fn.__module__}.{fn.__qualname__}"
        self._by_structure: collections.OrderedDict = collections.OrderedDict()  # (statics, tree, avals) -> program
        self._by_digest: collections.OrderedDict = collections.OrderedDict()  # digest -> program
        #: this function's programs: traced (and exported), loaded from disk, reused from memory
        #: for another structure-equal argument set, and plain ``jax.jit`` calls that compiled
        self.counts = collections.Counter()
        functools.update_wrapper(self, fn)
        _FUNCTIONS.add(self)

    def _top_level_jit(self):
        """The jitted function with its compiler options (made at its first use, when the
        backend is known), for calls with concrete arguments."""
        if self._top_jit is None:
            options = self._options()
            self._top_jit = jax.jit(self.fn, static_argnums=self.static_argnums, **options) if options else self.jit
        return self._top_jit

    def _options(self) -> dict:
        """``compiler_options=`` for ``jax.jit``: the function's XLA options for this backend."""
        options = self._compiler_options() if self._compiler_options is not None else None
        return {"compiler_options": options} if options else {}

    def __getattr__(self, name):  # lower, trace, eval_shape, _cache_size, ...: those of the jit a call would use
        return getattr(self.jit if _tracing() else self._top_level_jit(), name)

    def clear(self) -> None:
        """Forget the programs loaded in this process (the disk keeps them)."""
        self._by_structure.clear()
        self._by_digest.clear()

    def __call__(self, *args):
        where = directory()
        statics = tuple(args[i] for i in self.static_argnums)
        dynamic = tuple(a for i, a in enumerate(args) if i not in self.static_argnums)
        leaves, tree = jax.tree_util.tree_flatten(dynamic)
        traced = under_trace(leaves)
        mesh = None if (self.mesh_of is None or traced) else self.mesh_of(*statics)
        if where is None or traced:
            return self._timed_jit(args, mesh, traced)
        if mesh is None and jax.process_count() == 1:  # (across processes JAX places the call itself)
            leaves = _committed(leaves)
        try:
            memory_key = (statics, tree, tuple(_aval(x) for x in leaves), _session())
            hash(memory_key)
        except TypeError:
            return self._timed_jit(args, mesh)
        program = self._by_structure.get(memory_key)
        if program is None:
            t0 = time.perf_counter()
            try:
                program = self._program(where, statics, tree, leaves, mesh)
            except _Unkeyable:
                return self._timed_jit(args, mesh)
            out = program[0](*leaves)
            jax.block_until_ready(out)
            COMPILE_SECONDS[0] += time.perf_counter() - t0
            _remember(self._by_structure, memory_key, program)
        else:
            self._by_structure.move_to_end(memory_key)
            out = program[0](*leaves)
        return jax.tree_util.tree_unflatten(program[1], out)

    def _jit_for(self, mesh, traced: bool = False):
        """The plain jitted function (``traced``: inside another transformation, without the
        compiler options), for a sharded program with replicated arguments and results."""
        if mesh is None:
            return self.jit if traced else self._top_level_jit()
        if mesh not in self._sharded_jits:
            rep = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
            self._sharded_jits[mesh] = jax.jit(self.fn, static_argnums=self.static_argnums, in_shardings=rep,
                                               out_shardings=rep, **self._options())
        return self._sharded_jits[mesh]

    def _timed_jit(self, args, mesh=None, traced: bool = False):
        """The plain jitted call; its time counts as compiling when JAX's cache grew."""
        jitted = self._jit_for(mesh, traced)
        before = jitted._cache_size()
        t0 = time.perf_counter()
        out = jitted(*args)
        if jitted._cache_size() > before:
            self.counts["jit"] += 1
            jax.block_until_ready(out)
            COMPILE_SECONDS[0] += time.perf_counter() - t0
        return out

    def _program(self, where: Path, statics, tree, leaves, mesh=None):
        """(jitted call of the exported program on the flat leaves, output tree): from this
        process, from disk, or traced and exported now."""
        h = hashlib.sha256(_environment() + _session())
        h.update(self.name.encode())
        _digest_value(statics, h)
        _digest_tree(tree, h)
        _digest_value(tuple(_aval(x) for x in leaves), h)
        digest = h.hexdigest()
        program = self._by_digest.get(digest)
        if program is not None:
            self.counts["reused"] += 1
            return program
        with _TRACING:
            program = self._by_digest.get(digest)  # (traced by another thread meanwhile)
            if program is not None:
                self.counts["reused"] += 1
                return program
            path = where / f"{digest}.jaxexp"
            program = _load(path, mesh, self._options())
            kind = "loaded" if program is not None else "traced"
            if program is None:
                program = self._export(tree, statics, leaves, path, mesh)
            COUNTS[kind] += 1
            self.counts[kind] += 1
            _remember(self._by_digest, digest, program)
        return program

    def _export(self, tree, statics, leaves, path: Path, mesh=None):
        holder = {}

        def flat(*flat_leaves):
            # host-only fields are not in the key: the trace must not read them
            dynamic = iter(_hide_host_only(tuple(jax.tree_util.tree_unflatten(tree, flat_leaves))))
            fixed = dict(zip(self.static_argnums, _hide_host_only(tuple(statics))))
            count = len(statics) + len(tree.children())  # (the dynamic arguments: a tuple)
            args = [fixed[i] if i in fixed else next(dynamic) for i in range(count)]
            out_leaves, holder["tree"] = jax.tree_util.tree_flatten(self.fn(*args))
            return tuple(out_leaves)

        exported = jax.export.export(jax.jit(flat, **_replicated(mesh)))(*(_abstract(x) for x in leaves))
        _save(path, exported, holder["tree"])
        return jax.jit(exported.call, **_replicated(mesh), **self._options()), holder["tree"]


def under_trace(*trees) -> bool:
    """Whether a call with these arguments (pytrees) is traced into a JAX transformation:
    one is tracing the caller (:func:`_tracing`) or an argument is a tracer. Such a call
    compiles into the enclosing program, which alone takes compiler options."""
    return _tracing() or any(isinstance(x, jax.core.Tracer) for x in jax.tree_util.tree_leaves(trees))


def _tracing() -> bool:
    """Whether a JAX transformation (``jit``, ``vmap``, ...) is tracing the caller: a cached
    function called there with concrete arguments (e.g. a rollout of fixed inputs inside the
    user's ``jax.jit``) is traced into it, as plain ``jax.jit`` (JAX refuses compiler
    options on a nested jit)."""
    try:
        from jax._src import core

        return not core.trace_state_clean()
    except (ImportError, AttributeError):  # pragma: no cover - private API moved: an op stages under a trace
        import jax.numpy as jnp

        return isinstance(jnp.zeros(()), jax.core.Tracer)


def _committed(leaves: list) -> list:
    """The leaves as arrays committed to one device (the first committed leaf's, else the
    default one). A jitted call is lowered once per pattern of committed and uncommitted
    arguments: a rollout continued from its own output (committed) beside fresh inputs
    (uncommitted) compiled its program a second time (``dano simulate bunny-drop``, cold:
    2 × 2.1 s)."""
    loose = [i for i, x in enumerate(leaves) if not (isinstance(x, jax.Array) and x.committed)]
    if not loose:
        return leaves
    arrays = [x for x in leaves if isinstance(x, jax.Array)]  # (uncommitted ones live on the default device)
    committed = [x for x in arrays if x.committed]
    device = next(iter((committed or arrays)[0].devices())) if arrays else jax.devices()[0]
    put = jax.device_put([leaves[i] for i in loose], device)  # only those not committed yet
    leaves = list(leaves)
    for i, x in zip(loose, put):
        leaves[i] = x
    return leaves


def _replicated(mesh) -> dict:
    """jit's keyword arguments for a program on ``mesh`` with every argument and result
    replicated (none for a single-device program)."""
    if mesh is None:
        return {}
    rep = jax.sharding.NamedSharding(mesh, jax.sharding.PartitionSpec())
    return {"in_shardings": rep, "out_shardings": rep}


def _remember(memory: collections.OrderedDict, key, program) -> None:
    with _LOCK:
        memory[key] = program
        memory.move_to_end(key)
        while len(memory) > _MEMORY_SIZE:
            memory.popitem(last=False)


_MAGIC = b"dano-exported-1\n"


def _save(path: Path, exported, out_tree) -> None:
    """Write the program atomically; a program that cannot be saved stays in memory only."""
    try:
        tree_bytes = pickle.dumps(out_tree)
        blob = _MAGIC + len(tree_bytes).to_bytes(8, "little") + tree_bytes + bytes(exported.serialize())
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
        tmp.write_bytes(blob)
        os.replace(tmp, path)
    except Exception:  # noqa: BLE001 - a read-only or full disk, an unpicklable tree: not an error
        pass


def _load(path: Path, mesh=None, options: dict | None = None):
    """(jitted call, output tree) of a saved program, or None (absent, or unreadable: then
    removed); a sharded program is called on ``mesh``; options: further ``jax.jit`` keywords."""
    try:
        blob = path.read_bytes()
    except OSError:
        return None
    try:
        if not blob.startswith(_MAGIC):
            raise ValueError("not a dano program")
        at = len(_MAGIC)
        n = int.from_bytes(blob[at : at + 8], "little")
        out_tree = pickle.loads(blob[at + 8 : at + 8 + n])
        exported = jax.export.deserialize(bytearray(blob[at + 8 + n :]))
        if exported.nr_devices != (1 if mesh is None else mesh.size):
            raise ValueError("exported for another number of devices")
        return jax.jit(exported.call, **_replicated(mesh), **(options or {})), out_tree
    except Exception:  # noqa: BLE001 - a truncated or foreign file: trace again
        try:
            path.unlink()
        except OSError:
            pass
        return None


def clear() -> None:
    """Forget every program loaded in this process (the disk keeps them), e.g. beside
    ``jax.clear_caches()`` to free memory."""
    for f in list(_FUNCTIONS):
        f.clear()


def cached_jit(fn=None, *, static_argnums=(), mesh=None, compiler_options=None):
    """``jax.jit`` whose traced program is kept per structure, across processes (module
    documentation). Use as ``cached_jit(fn, static_argnums=(0,))`` or as a decorator.
    mesh: for a function that shards its work with ``shard_map``, ``mesh(*static
    arguments)`` -> the Mesh it runs on, or None for a single-device call.
    compiler_options: a function () -> dict of XLA options for ``jax.jit(...,
    compiler_options=)`` (or None), called at the first compile, when the backend is known
    (:func:`dano._jax_setup.rollout_compiler_options`)."""
    if fn is None:
        return functools.partial(cached_jit, static_argnums=static_argnums, mesh=mesh,
                                 compiler_options=compiler_options)
    return CachedFunction(fn, static_argnums, mesh, compiler_options)
