"""What importing dano does to the process, and the explicit switches it offers.

Importing dano changes no JAX configuration. It sets two environment variables (XLA_FLAGS with
two flags), each only when the user has not set it and only when it can still take effect:

* ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false``, appended when JAX's backend has not
  started yet and the installed jaxlib knows the flag (before 0.11, which removed it): with
  jaxlib >= 0.8 the CPU fusion emitters make MJX steps of deep
  kinematic chains exponentially slow (one Franka Panda step: 0.45 s with them, 1.0 ms
  without; ``../shared/GUIDE.md``). If JAX started earlier without it,
  :func:`check_xla_flags` warns once (when :mod:`dano.sim` is imported).
* ``XLA_FLAGS=--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=10000000``,
  appended when JAX's backend has not started yet and the user's XLA_FLAGS hold no
  ``xla_backend_extra_options``: XLA's CPU compiler then turns a while loop whose body
  accesses fewer bytes than this (jaxlib's default: 1 kB) and calls no LAPACK into one
  compiled kernel. A rollout of a DANO scene with the step's Newton systems solved by
  :func:`dano.sim.implicit.dense_solve` is such a loop: the bunny drop's step runs in
  7.3 µs instead of 20.2 µs (:attr:`dano.sim.NewtonConfig.linear_solver`). A loop that
  calls LAPACK stays as it was: with the flag alone, the bunny drop's rollout compiled in
  1.53–1.55 s (1.51–1.54 s without) and stepped as fast; the Panda scene stepped in 247 µs
  (237 µs without, one run each). Other backends ignore it: XLA keeps ``xla_``-prefixed
  extra options to itself (it passes only the others on to LLVM), and only the CPU compiler
  reads this one.
* ``MUJOCO_GL`` when no display is set, the user has not set it and MuJoCo is not
  imported yet: headless machines render through EGL (``egl``), or OSMesa where there is
  no libEGL, and where there is neither, ``disable`` (MuJoCo then imports and simulates;
  rendering says it cannot create an OpenGL context): :func:`headless_gl_backend`.

Explicit switches (the ``dano`` command line turns both on):

* :func:`enable_float64` — JAX's 64-bit mode, for the whole process. dano computes in
  JAX's default float type: float32 unless 64-bit mode is on. Asset building (mass
  properties, samples, normals) always runs in float64 locally (``with
  jax.enable_x64(True)``); identification needs a float64 scene and says so otherwise.
* :func:`enable_compilation_cache` — JAX's persistent compilation cache in
  ``~/.cache/dano/jax`` (or ``$DANO_CACHE_DIR``), so the 5–20 s compiles of MJX functions
  are paid once per machine (small ones kept too).
"""

from __future__ import annotations

import functools
import importlib.metadata
import os
import sys
import warnings

# jax is imported inside the functions below, never at the top: this module must run before
# jax is imported, so that the XLA_FLAGS it sets still take effect.
FUSION_FLAG = "--xla_cpu_use_fusion_emitters=false"
#: XLA's CPU compiler turns a while loop (a rollout's scan, the step's Newton loop) whose
#: body reads and writes fewer bytes than this threshold, and that holds no custom call,
#: into one compiled kernel instead of running its operations one by one through the thunk
#: runtime (jaxlib's default threshold: 1 kB)
SMALL_LOOP_BYTES = 10_000_000
SMALL_LOOP_FLAG = f"--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold={SMALL_LOOP_BYTES}"


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # pragma: no cover - private API moved
        return True


def jaxlib_has_fusion_flag() -> bool:
    """Whether the installed jaxlib knows ``--xla_cpu_use_fusion_emitters`` (before 0.11; jaxlib
    0.11 removed it and aborts at start-up on an unknown XLA flag). Read from the package's
    metadata, without importing it."""
    try:
        parts = importlib.metadata.version("jaxlib").split(".")[:2]
        return tuple(int("".join(c for c in p if c.isdigit()) or 0) for p in parts) < (0, 11)
    except (importlib.metadata.PackageNotFoundError, ValueError):  # pragma: no cover - no jaxlib: nothing to configure
        return False


def headless_gl_backend() -> str:
    """MuJoCo's OpenGL back-end for a machine without a display: ``egl`` where the system
    has libEGL, else ``osmesa`` where it has libOSMesa, else ``disable``. PyOpenGL does not
    fail cleanly when told to use EGL without libEGL: ``import mujoco`` itself then raised
    AttributeError ('NoneType' object has no attribute 'eglQueryString'), seen on a GPU
    machine with CUDA but no OpenGL libraries (2026-11-25); with ``disable`` MuJoCo imports
    and simulates, and only rendering fails, with dano's message naming MUJOCO_GL."""
    import ctypes.util

    for backend, library in (("egl", "EGL"), ("osmesa", "OSMesa")):
        if ctypes.util.find_library(library):
            return backend
    return "disable"


_STARTED_BEFORE_US = _backend_started()
_FLAG_BEFORE_US = FUSION_FLAG in os.environ.get("XLA_FLAGS", "")
if not _STARTED_BEFORE_US and "xla_cpu_use_fusion_emitters" not in os.environ.get("XLA_FLAGS", "") \
        and jaxlib_has_fusion_flag():
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + FUSION_FLAG).strip()
if not _STARTED_BEFORE_US and "xla_backend_extra_options" not in os.environ.get("XLA_FLAGS", ""):
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") + " " + SMALL_LOOP_FLAG).strip()
if not os.environ.get("DISPLAY") and "mujoco" not in sys.modules and "MUJOCO_GL" not in os.environ:
    os.environ["MUJOCO_GL"] = headless_gl_backend()


#: XLA's CPU option that picks which operations become YNNPACK library fusions (dots,
#: reductions, element-wise); empty: none (:func:`rollout_compiler_options`)
YNN_OPTION = "xla_cpu_experimental_ynn_fusion_type"


#: XLA's GPU option listing the commands that run as command buffers (CUDA graphs)
COMMAND_BUFFER_OPTION = "xla_gpu_enable_command_buffer"
#: on a GPU, an explicit list: XLA's usual commands (fusions, cuBLAS, custom calls, cuDNN)
#: and also while loops and conditionals: a data-dependent loop (the step's Newton
#: iterations, its line search) then runs as a CUDA graph conditional node, its test on the
#: GPU, instead of one host round trip per iteration
GPU_COMMAND_BUFFERS = "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,CONDITIONAL,WHILE"


def _nvidia() -> bool:
    """Whether the default device is an NVIDIA GPU (CUDA: graphs with conditional nodes)."""
    import jax

    device = jax.devices()[0]
    version = str(getattr(device.client, "platform_version", "")).lower()
    return "cuda" in version or "nvidia" in str(getattr(device, "device_kind", "")).lower()


def _compiles_with(options: dict) -> bool:
    """Whether this jaxlib compiles and runs a tiny function with a loop under these XLA
    options (a driver without CUDA graph conditional nodes fails at run time)."""
    import jax

    try:
        jax.jit(lambda x: jax.lax.while_loop(lambda c: c < 3.0, lambda c: c + 1.0, x),
                compiler_options=options).lower(1.0).compile()(1.0).block_until_ready()
    except Exception:  # noqa: BLE001 - an XLA without the option: compile as it comes
        return False
    return True


@functools.lru_cache(maxsize=1)
def batched_compiler_options() -> dict:
    """XLA options of a batched (``vmap``-ed) rollout's compile: on an NVIDIA GPU, while loops
    and conditionals in command buffers (:data:`GPU_COMMAND_BUFFERS`, with graphs of any size).
    A data-dependent loop (the step's Newton iterations, its line search) then runs as a CUDA
    graph conditional node with its test on the GPU, not one host round trip per iteration:
    16,384 vmapped 200-step bunny drops in float32 ran at 8.07M env-steps/s instead of 7.18M
    (LAPACK solves) and 8.86M instead of 7.56M (unrolled LU) on one H200 (docs/scaling.md).
    Since the batched line search stopped halving for envs that need no halving (2026-11-26),
    the gain is small: 9.89M against 9.60M (LAPACK) and 11.84M against 11.83M (unrolled LU) on
    one H100.
    Plain MJX's step ran slower so (2.38M -> 2.03M): an option of dano's rollouts, not a
    process-wide flag. Empty on other backends (on the CPU the batched bunny drops ran 14–17 %
    faster with XLA's defaults than with :func:`rollout_compiler_options`' YNNPACK setting), where
    the user's XLA_FLAGS set the option, or where this jaxlib does not take it (tried once)."""
    import jax

    if jax.default_backend() != "gpu" or COMMAND_BUFFER_OPTION in os.environ.get("XLA_FLAGS", "") or not _nvidia():
        return {}
    options = {COMMAND_BUFFER_OPTION: GPU_COMMAND_BUFFERS, "xla_gpu_graph_min_graph_size": 1}
    return options if _compiles_with(options) else {}


@functools.lru_cache(maxsize=1)
def rollout_compiler_options() -> dict:
    """XLA options of a rollout's compile (``jax.jit(..., compiler_options=)``): on the CPU,
    no YNNPACK fusions. A YNNPACK fusion runs as a library call, and XLA's CPU compiler
    turns a while loop into one kernel only when nothing in it calls out
    (:data:`SMALL_LOOP_FLAG`): the per-sample model's sums over its samples became such
    fusions, so its rollouts ran op by op (bunny drop, 2-core CPU: 50–53 µs per step, 22
    µs as one kernel). The centroid model's rollout has none in its loop and steps as fast
    either way (7.4 µs).

    Empty where the backend is not the CPU (batched programs on a GPU:
    :func:`batched_compiler_options`; a single rollout on a GPU was not measured with them),
    where the user's XLA_FLAGS set the option, or where this jaxlib does not know it (tried
    once on a tiny function with a loop)."""
    import jax

    if jax.default_backend() != "cpu" or YNN_OPTION in os.environ.get("XLA_FLAGS", ""):
        return {}
    options = {YNN_OPTION: ""}
    return options if _compiles_with(options) else {}


def check_xla_flags() -> bool:
    """Return True if the CPU backend runs with the fusion-emitter flag off.

    Warns (once) when JAX was initialised before :mod:`dano` was imported, in which
    case MJX steps of robots can be ~400x slower on CPU.
    """
    if _STARTED_BEFORE_US and not _FLAG_BEFORE_US and jaxlib_has_fusion_flag():
        warnings.warn(
            "JAX was started before dano was imported, without "
            f"XLA_FLAGS={FUSION_FLAG}; MJX steps of articulated robots may be "
            "very slow on CPU. Import dano first or export the flag.",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    return True


def enable_float64() -> None:
    """Turn on JAX's 64-bit mode for this process (``jax_enable_x64``): scenes composed
    afterwards simulate in float64. Call it before creating arrays you mean to use."""
    import jax

    jax.config.update("jax_enable_x64", True)


def enable_compilation_cache(path: str | None = None) -> str:
    """Turn on JAX's persistent compilation cache in ``path`` (default
    ``$DANO_CACHE_DIR`` or ``~/.cache/dano/jax``) for every compilation, small ones included
    (JAX's default keeps only those over 1 s: a warm ``dano sysid soap`` then compiled its
    ~70 small programs again, 7.7 s vs 6.8-7.1 s with all kept; the cache grew 1.6 -> 1.9 MB);
    returns it."""
    import jax

    path = path or os.environ.get("DANO_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "dano", "jax"))
    jax.config.update("jax_compilation_cache_dir", path)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    return path


def in_float64(fn):
    """Decorator: run ``fn`` with JAX's 64-bit mode on (``jax.enable_x64(True)``), whatever
    the process-wide setting; for computations that must be float64 (asset building)."""
    @functools.wraps(fn)
    def wrapped(*args, **kwargs):
        import jax

        with jax.enable_x64(True):
            return fn(*args, **kwargs)

    return wrapped
