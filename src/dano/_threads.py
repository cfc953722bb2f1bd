"""Work side by side in threads, within one process: the calls dano overlaps.

XLA compiles and runs a program without Python's lock, so on a machine with a second core
one program can compile (or a local solve run) while Python traces another. Every call
computes what it would alone: results never depend on the threads. Across processes
(``jax.distributed``) every process must start the same programs in the same order, so
there the calls run one after another, in the caller's thread.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import jax

from .errors import DanoError


def or_error(call):
    """``call()``, or the DanoError it raised (other exceptions propagate)."""
    try:
        return call()
    except DanoError as exc:
        return exc


def _in_this_context(call):
    """``call`` as a function to run in another thread with this thread's 64-bit mode
    (``jax.enable_x64`` is thread-local: a new thread starts from the global setting),
    giving DanoError as a result (:func:`or_error`)."""
    x64 = bool(jax.config.jax_enable_x64)

    def run():
        with jax.enable_x64(x64):
            return or_error(call)
    return run


def cores() -> int:
    """The CPU cores this process may run on."""
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


def side_by_side(calls: list, warm=None) -> list:
    """The results of ``calls`` (functions of no argument), in order, run in threads, as many
    at a time as the machine has cores; a call that raises DanoError gives that error in its
    place (other exceptions propagate). Local solves whose time is in their residual and
    Jacobian programs run side by side: on two cores the soap's two starts take about the
    time of one. ``warm`` (a function of no argument, e.g. what :func:`in_background`
    returns) runs first, alone, so that the calls do not compile the same program twice."""
    workers = min(len(calls), cores()) if jax.process_count() == 1 else 1
    if warm is not None:
        or_error(warm)
    if workers <= 1:
        return [or_error(c) for c in calls]
    runs = [_in_this_context(c) for c in calls]
    with ThreadPoolExecutor(max_workers=workers) as pool:
        return list(pool.map(lambda run: run(), runs))


def in_background(call):
    """Start ``call`` (a function of no argument) in a thread where the machine has a second
    core and a single process runs. Returns a function of no argument that waits for it and
    gives its result, or the DanoError it raised (other exceptions propagate there); without
    a thread the call runs when that function is called. Used to compile (or load) a
    program that will be needed while Python traces or runs another: cold on two cores,
    ``dano sysid soap`` 20.8 s -> 16.3 s (``benchmarks/latency-cpu.json``)."""
    if cores() < 2 or jax.process_count() > 1:
        return _in_this_context(call)
    pool = ThreadPoolExecutor(max_workers=1)
    future = pool.submit(_in_this_context(call))
    pool.shutdown(wait=False)
    return future.result
