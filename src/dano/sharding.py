"""Batches over devices and hosts: dano's batched work split along its batch axis with
``jax.sharding`` and ``jax.shard_map``, and several processes joined by ``jax.distributed``.

One axis, ``"batch"``: a 1-D :class:`jax.sharding.Mesh` over the devices in use
(:func:`batch_mesh`: the first ``devices`` local devices of every process, processes in
order). A batched function runs as ``jax.jit(jax.shard_map(jax.vmap(fn)))``: each device
runs the same per-device program on its rows (no communication inside), batches that do
not divide are padded by repeating their last row (the padded rows are dropped from the
result). One device is plain ``jax.jit(jax.vmap(fn))``, unchanged.

Which devices: all local devices by default; :func:`use_devices` limits them for a block of
code (the command line's ``--devices N``), e.g. ::

    with dano.sharding.use_devices(2):
        result = dano.sysid.identify(problem)

Across hosts: :func:`initialize` (``jax.distributed.initialize``; options or environment
variables ``DANO_COORDINATOR_ADDRESS``, ``DANO_NUM_PROCESSES``, ``DANO_PROCESS_ID``, CPU
collectives by gloo) before any JAX computation; then every process runs the same program
(SPMD), the mesh spans every process's devices and the results are gathered on every host.
:func:`load_shares` lets each process load only its share of the inputs (e.g. trajectory
files) and hands every process the whole list. See docs/scaling.md.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import pickle
from typing import Callable, Mapping, Sequence

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from ._compiled import under_trace
from ._jax_setup import batched_compiler_options
from .errors import DanoError

#: the name of the mesh axis that batches are split along
AXIS = "batch"

_DEVICES: contextvars.ContextVar[int | None] = contextvars.ContextVar("dano_devices", default=None)

#: environment variables read by :func:`initialize` (and by the ``dano`` command line)
ENV_COORDINATOR, ENV_PROCESSES, ENV_PROCESS_ID = "DANO_COORDINATOR_ADDRESS", "DANO_NUM_PROCESSES", "DANO_PROCESS_ID"


# ------------------------------------------------------------------ which devices
def check_devices(devices, option: str = "devices") -> int:
    """``devices`` validated as a number of this process's devices to use (1 to
    ``jax.local_device_count()``); None: all of them. Raises a one-line DanoError naming
    ``option`` otherwise (e.g. ``--devices 0``). Starts JAX's backend."""
    available = jax.local_device_count()
    if devices is None:
        return available
    if isinstance(devices, bool) or not isinstance(devices, (int, np.integer)) or not 1 <= devices <= available:
        raise DanoError(f"{option} must be 1 to {available} (the {jax.default_backend()} devices of this process), "
                        f"got {devices!r}")
    return int(devices)


@contextlib.contextmanager
def use_devices(devices: int | None, option: str = "devices"):
    """Within the block, dano's batched functions use the first ``devices`` local devices
    of each process (None: all; checked by :func:`check_devices`). Yields the number."""
    n = check_devices(devices, option)
    token = _DEVICES.set(n)
    try:
        yield n
    finally:
        _DEVICES.reset(token)


def devices_in_use() -> int:
    """Local devices per process that batched functions use now (:func:`use_devices`; by
    default all of ``jax.local_device_count()``)."""
    n = _DEVICES.get()
    return jax.local_device_count() if n is None else n


def batch_mesh(per_process: int | None = None) -> Mesh:
    """A 1-D mesh (axis :data:`AXIS`) over the first ``per_process`` local devices of every
    process (default :func:`devices_in_use`), processes in order: its size is
    ``per_process × jax.process_count()``."""
    per = devices_in_use() if per_process is None else check_devices(per_process)
    by_process: dict[int, list] = {}
    for d in jax.devices():
        by_process.setdefault(d.process_index, []).append(d)
    chosen = [d for p in sorted(by_process) for d in sorted(by_process[p], key=lambda d: d.id)[:per]]
    return Mesh(np.array(chosen), (AXIS,))


def mesh_of_size(shards: int) -> Mesh | None:
    """The batch mesh of ``shards`` devices in all (``shards / process_count`` per process),
    or None for one device (no mesh: the plain single-device program)."""
    if shards == 1:
        return None
    processes = jax.process_count()
    if shards % processes:
        raise DanoError(f"{shards} shards do not split evenly over {processes} processes")
    return batch_mesh(shards // processes)


def shards_for(rows: int, per_process: int | None = None) -> int:
    """How many devices (in all processes) a batch of ``rows`` rows is split over: as few
    as give each device no more rows than using every device in use would (10 rows on 8
    devices: 2 rows each either way, so 5 devices and no padding; 3 rows on 8: 3 devices),
    the same number in every process (each takes part)."""
    per = devices_in_use() if per_process is None else per_process
    processes = jax.process_count()
    each = max(1, -(-rows // (per * processes)))  # rows per device with every device in use
    return max(1, min(per, -(-rows // (each * processes)))) * processes


def padded_size(rows: int, shards: int) -> int:
    """``rows`` rounded up to a multiple of ``shards``."""
    return -(-rows // shards) * shards


def pad_rows(tree, size: int):
    """Every leaf of ``tree`` (leading axis: rows) padded to ``size`` rows by repeating its
    last row (repeated real rows keep padded work finite; their results are dropped)."""
    def pad(x):
        n = np.shape(x)[0]
        if n == size:
            return x
        if n == 0 or n > size:
            raise DanoError(f"cannot pad a batch of {n} rows to {size}")
        xp = jax.numpy if isinstance(x, jax.Array) else np
        return xp.concatenate([x, xp.repeat(x[-1:], size - n, axis=0)])
    return jax.tree_util.tree_map(pad, tree)


def replicated(mesh: Mesh) -> NamedSharding:
    """The sharding that keeps a whole copy on every device of ``mesh``."""
    return NamedSharding(mesh, PartitionSpec())


def rows(mesh: Mesh) -> NamedSharding:
    """The sharding that splits the leading axis over ``mesh``'s devices."""
    return NamedSharding(mesh, PartitionSpec(AXIS))


def map_rows(fn: Callable, in_axes, batch_size: int | None = None) -> Callable:
    """``jax.vmap(fn, in_axes)`` (in_axes: 0 or None per positional argument), or, with
    ``batch_size``, the same rows evaluated ``batch_size`` at a time by ``jax.lax.map``
    (a loop over vmapped chunks; one at a time: a plain loop; the values are the same): on a
    CPU a vmap of many rollouts can be slower than the loop
    (:func:`dano.sysid.problem.batch_chunk` has measurements)."""
    if batch_size is None:
        return jax.vmap(fn, in_axes=in_axes)

    def mapped(*args):
        rows = tuple(a for a, ax in zip(args, in_axes) if ax == 0)

        def one(row):
            it = iter(row)
            return fn(*(next(it) if ax == 0 else a for a, ax in zip(args, in_axes)))
        # (one at a time: a plain loop, not chunks of one, whose vmapped loops keep their selects)
        return jax.lax.map(one, rows, batch_size=None if batch_size == 1 else batch_size)
    return mapped


def split_rows(fn: Callable, mesh: Mesh | None, in_axes, batch_size: int | None = None) -> Callable:
    """``jax.vmap(fn, in_axes)`` with the rows (arguments whose axis is 0) split over
    ``mesh``'s devices by ``jax.shard_map`` (arguments with axis None are whole on every
    device); the result's rows are split likewise. For use inside a jitted function: the
    number of rows must be a multiple of the mesh's size (:func:`pad_rows`). None: vmap only.
    batch_size: each device's rows evaluated that many at a time (:func:`map_rows`)."""
    mapped = map_rows(fn, in_axes, batch_size)
    if mesh is None or mesh.size == 1:
        return mapped
    specs = tuple(PartitionSpec(AXIS) if a == 0 else PartitionSpec() for a in in_axes)
    # check_vma=False: MJX's loops carry values that the varying-axis type check cannot
    # follow (a scan's carry starts replicated and becomes per-device); the body has no
    # collectives, so there is nothing for the check to protect
    return jax.shard_map(mapped, mesh=mesh, in_specs=specs, out_specs=PartitionSpec(AXIS), check_vma=False)


def sharded_vmap(fn: Callable, in_axes: Sequence[int | None] | int = 0, devices: int | None = None,
                 compiler_options: dict | None = None) -> Callable:
    """``jax.jit(jax.vmap(fn, in_axes))`` with the batch split over the devices in use (or the
    first ``devices`` local ones of each process): the batch (the leading axis of the
    arguments with axis 0; every leaf of a pytree argument) is padded to a multiple of the
    mesh's size, split by :func:`split_rows`, and the padding is dropped from the result.
    in_axes: 0 or None per positional argument (None: the same for every row). One device:
    ``jax.jit(jax.vmap(fn))`` itself. Results are those of one device (the per-device
    program is the same; float64 agrees to rounding). Across processes every process passes
    the whole batch (the same values) and gets the whole result. compiler_options: XLA
    options of the program (``jax.jit(compiler_options=)``); None: a batched rollout's
    (:func:`dano.sim.batched_compiler_options`: on an NVIDIA GPU the Newton loops run as
    CUDA graphs), ``{}``: XLA's defaults."""
    if compiler_options is not None and not isinstance(compiler_options, Mapping):
        raise DanoError(f"compiler_options must be a mapping of XLA option names to values, got {compiler_options!r}")
    compiled: dict = {}
    options = batched_compiler_options() if compiler_options is None else dict(compiler_options)

    def run(*args):
        axes = tuple(in_axes) if isinstance(in_axes, (tuple, list)) else (in_axes,) * len(args)
        if len(axes) != len(args) or any(a not in (0, None) for a in axes):
            raise DanoError(f"in_axes must be 0 or None for each of the {len(args)} arguments, got {in_axes!r}")
        # (inside the user's jit, vmap or grad the program is traced into theirs: JAX takes
        # compiler options on a top-level jit only)
        jit_options = {} if under_trace(args) or not options else {"compiler_options": options}
        per = devices_in_use() if devices is None else check_devices(devices)
        batched = [a for a, ax in zip(args, axes) if ax == 0]
        if not batched:
            raise DanoError("sharded_vmap needs at least one argument with axis 0")
        size = int(np.shape(jax.tree_util.tree_leaves(batched[0])[0])[0])
        mesh = mesh_of_size(shards_for(size, per))
        if mesh is None:
            key = (None, bool(jit_options))
            if key not in compiled:
                compiled[key] = jax.jit(jax.vmap(fn, in_axes=axes), **jit_options)
            return compiled[key](*args)
        padded = padded_size(size, mesh.size)
        args = tuple(pad_rows(a, padded) if ax == 0 else a for a, ax in zip(args, axes))
        key = (mesh, bool(jit_options))
        if key not in compiled:
            if jax.process_count() > 1:  # every process holds the whole batch and gets the whole result
                shard = dict(in_shardings=replicated(mesh), out_shardings=replicated(mesh))
            else:
                shard = dict(in_shardings=tuple(rows(mesh) if ax == 0 else replicated(mesh) for ax in axes))
            compiled[key] = jax.jit(split_rows(fn, mesh, axes), **jit_options, **shard)
        out = compiled[key](*args)
        return out if padded == size else jax.tree_util.tree_map(lambda x: x[:size], out)

    return run


# ------------------------------------------------------------------ across hosts
def initialize(coordinator_address: str | None = None, num_processes: int | None = None,
               process_id: int | None = None, local_device_ids: Sequence[int] | None = None) -> dict:
    """Join this process to a multi-process run (``jax.distributed.initialize``), before any
    JAX computation. Arguments left None come from ``$DANO_COORDINATOR_ADDRESS`` (host:port
    of process 0's coordinator service), ``$DANO_NUM_PROCESSES`` and ``$DANO_PROCESS_ID``
    (0 … n−1), or, where those are unset too, JAX's own detection (Slurm, Open MPI,
    Kubernetes, ``$JAX_COORDINATOR_ADDRESS``). On CPU, collectives go through gloo. Returns
    {"process_id", "num_processes", "local_devices", "devices"}. Raises DanoError naming the
    option or variable when a value is bad or JAX has already started."""
    from . import _jax_setup

    if jax.distributed.is_initialized():
        return _topology()

    def number(value, env, what):
        if value is None and os.environ.get(env, "").strip():
            try:
                value = int(os.environ[env])
            except ValueError:
                raise DanoError(f"${env} must be an integer ({what}), got {os.environ[env]!r}") from None
        return value

    coordinator_address = coordinator_address or os.environ.get(ENV_COORDINATOR) or None
    num_processes = number(num_processes, ENV_PROCESSES, "the number of processes")
    process_id = number(process_id, ENV_PROCESS_ID, "this process's index")
    if num_processes is not None and num_processes < 1:
        raise DanoError(f"num_processes (${ENV_PROCESSES}) must be >= 1, got {num_processes}")
    if process_id is not None and num_processes is not None and not 0 <= process_id < num_processes:
        raise DanoError(f"process_id (${ENV_PROCESS_ID}) must be 0 to {num_processes - 1}, got {process_id}")
    if coordinator_address is not None and ":" not in coordinator_address:
        raise DanoError(f"coordinator_address (${ENV_COORDINATOR}) must be host:port, got {coordinator_address!r}")
    if _jax_setup._backend_started():
        raise DanoError("jax.distributed must be initialised before any JAX computation: call "
                        "dano.sharding.initialize() (or set $DANO_NUM_PROCESSES) first")
    jax.config.update("jax_cpu_collectives_implementation", "gloo")
    try:
        jax.distributed.initialize(coordinator_address=coordinator_address, num_processes=num_processes,
                                   process_id=process_id, local_device_ids=local_device_ids)
    except (ValueError, RuntimeError) as exc:
        raise DanoError(f"jax.distributed.initialize failed: {' '.join(str(exc).split())}") from exc
    if jax.default_backend() == "cpu":
        _connect_quietly()
    return _topology()


def _connect_quietly() -> None:
    """One barrier over every device, with this process's standard output sent to standard
    error meanwhile: gloo announces its first connection ("[Gloo] Rank 0 is connected to 1
    peer ranks") on standard output, where it would break a command's JSON output."""
    import sys

    from jax.experimental import multihost_utils

    sys.stdout.flush()
    saved = os.dup(1)
    try:
        os.dup2(2, 1)
        multihost_utils.sync_global_devices("dano.sharding.initialize")
    finally:
        sys.stdout.flush()
        os.dup2(saved, 1)
        os.close(saved)


def _topology() -> dict:
    return {"process_id": jax.process_index(), "num_processes": jax.process_count(),
            "local_devices": jax.local_device_count(), "devices": jax.device_count()}


def initialize_from_environment() -> dict | None:
    """:func:`initialize` when ``$DANO_NUM_PROCESSES`` is set (what the ``dano`` command
    line does first), else None (one process)."""
    if not os.environ.get(ENV_PROCESSES, "").strip():
        return None
    return initialize()


def share(count: int, process: int | None = None, processes: int | None = None) -> range:
    """The indices of ``count`` items that process ``process`` (default this one) of
    ``processes`` handles: contiguous, balanced blocks in process order."""
    process = jax.process_index() if process is None else process
    processes = jax.process_count() if processes is None else processes
    return range(process * count // processes, (process + 1) * count // processes)


def allgather_objects(obj) -> list:
    """Every process's ``obj`` (picklable), in process order, on every process (one process:
    ``[obj]``). Collective: every process must call it."""
    if jax.process_count() == 1:
        return [obj]
    from jax.experimental import multihost_utils

    blob = np.frombuffer(pickle.dumps(obj), dtype=np.uint8)
    sizes = np.asarray(multihost_utils.process_allgather(np.array([blob.size], dtype=np.int32))).reshape(-1)
    buffer = np.zeros(int(sizes.max()), dtype=np.uint8)
    buffer[: blob.size] = blob
    gathered = np.asarray(multihost_utils.process_allgather(buffer)).reshape(len(sizes), -1)
    return [pickle.loads(gathered[p, : sizes[p]].tobytes()) for p in range(len(sizes))]


def load_shares(items: Sequence, load: Callable) -> list:
    """``[load(x) for x in items]``, each process loading only its :func:`share` of ``items``
    (e.g. trajectory files) and receiving the others' through :func:`allgather_objects`:
    every process gets the whole list, in order (the results must be picklable). Collective
    across processes: an error while one process loads is raised on every process (the
    first process's first error), so that none waits for the others."""
    if jax.process_count() == 1:
        return [load(x) for x in items]
    try:
        mine = (None, [load(items[i]) for i in share(len(items))])
    except Exception as exc:  # noqa: BLE001 - handed to every process, raised there
        try:
            pickle.dumps(exc)
            mine = (exc, None)
        except Exception:  # noqa: BLE001 - an exception that cannot travel: its message does
            mine = (DanoError(str(exc)), None)
    parts = allgather_objects(mine)
    for error, _ in parts:
        if error is not None:
            raise error
    return [x for _, part in parts for x in part]
