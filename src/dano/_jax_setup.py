"""Process-wide JAX set-up, applied once when :mod:`dano` is imported.

* ``XLA_FLAGS=--xla_cpu_use_fusion_emitters=false``: with jaxlib >= 0.8 the CPU
  fusion emitters make MJX steps of deep kinematic chains exponentially slow
  (one Franka Panda step: 0.45 s with them, 1.0 ms without; ``../shared/GUIDE.md``).
  XLA reads the flag when the CPU backend starts, so it is only effective if
  ``dano`` is imported before the first JAX computation. If JAX was started
  earlier without it, :func:`check_xla_flags` warns once.
* ``jax_enable_x64``: mass properties, gradient checks and identification need
  float64 (guide: finite differences are only meaningful in float64).
* ``MUJOCO_GL=egl`` when no display is set (and the user chose nothing): MuJoCo picks
  its OpenGL platform when it is imported, and headless machines render through EGL.
* A persistent compilation cache (``~/.cache/dano/jax``, or ``$DANO_CACHE_DIR``)
  so that the 5-20 s compiles of MJX functions are paid once per machine.
"""

from __future__ import annotations

import os
import sys
import warnings

FUSION_FLAG = "--xla_cpu_use_fusion_emitters=false"


def _set_xla_flags() -> None:
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" not in flags:
        os.environ["XLA_FLAGS"] = (flags + " " + FUSION_FLAG).strip()


def _backend_started() -> bool:
    if "jax" not in sys.modules:
        return False
    try:
        from jax._src import xla_bridge

        return bool(getattr(xla_bridge, "_backends", {}))
    except Exception:  # pragma: no cover - private API moved
        return True


_STARTED_BEFORE_US = _backend_started()
_FLAG_BEFORE_US = FUSION_FLAG in os.environ.get("XLA_FLAGS", "")
_set_xla_flags()
if not os.environ.get("DISPLAY") and "mujoco" not in sys.modules:
    os.environ.setdefault("MUJOCO_GL", "egl")

import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
_cache = os.environ.get("DANO_CACHE_DIR", os.path.join(os.path.expanduser("~"), ".cache", "dano", "jax"))
try:
    jax.config.update("jax_compilation_cache_dir", _cache)
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 1.0)
except Exception:  # pragma: no cover - older/newer jax without these options
    pass


def check_xla_flags() -> bool:
    """Return True if the CPU backend runs with the fusion-emitter flag off.

    Warns (once) when JAX was initialised before :mod:`dano` was imported, in which
    case MJX steps of robots can be ~400x slower on CPU.
    """
    if _STARTED_BEFORE_US and not _FLAG_BEFORE_US:
        warnings.warn(
            "JAX was started before dano was imported, without "
            f"XLA_FLAGS={FUSION_FLAG}; MJX steps of articulated robots may be "
            "very slow on CPU. Import dano first or export the flag.",
            RuntimeWarning,
            stacklevel=2,
        )
        return False
    return True
