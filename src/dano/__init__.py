"""dano: differentiable simulation of dynamics-augmented neural objects (DANOs).

The flat public API; stages live in submodules: :mod:`dano.fields` (density fields),
:mod:`dano.asset` (mass properties, boundary samples, ``.dano`` files), :mod:`dano.io`
(importers), :mod:`dano.contact` (overlap and force law), :mod:`dano.sim` (scenes and
rollouts on MJX), :mod:`dano.sysid` (identification), :mod:`dano.viz` (plots, videos).
Simulation and identification names load lazily (they import MuJoCo MJX).
"""

from . import _jax_setup  # noqa: F401  (must run before anything imports jax)
from ._jax_setup import enable_compilation_cache, enable_float64  # noqa: E402

from ._version import __version__  # noqa: E402,F401

from .asset import DanoAsset, MassProperties, boundary_samples, build, load, mass_properties, save  # noqa: E402
from .data import load_builtin  # noqa: E402
from .errors import DanoError, DanoWarning, FileFormatError  # noqa: E402
from .io import load_paper_collider  # noqa: E402

_LAZY = {
    "DanoObject": "sim", "NewtonConfig": "sim", "NewtonOptions": "sim", "Scene": "sim", "SimParams": "sim",
    "SimulationDiverged": "sim",
    "State": "sim", "compose": "sim", "make_data": "sim", "rollout": "sim", "rollout_arrays": "sim", "step": "sim",
    "Trajectory": "trajectory", "save_trajectory": "trajectory", "load_trajectory": "trajectory",
    "ContactParams": "contact", "FitParameter": "sysid", "Observation": "sysid", "SysIdProblem": "sysid",
    "identify": "sysid", "load_scene": "sim.scenes",
}


def __getattr__(name):
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(f".{_LAZY[name]}", __name__), name)
    raise AttributeError(f"module 'dano' has no attribute {name!r}")


__all__ = sorted(_LAZY) + [
    "DanoAsset",
    "DanoError",
    "DanoWarning",
    "enable_compilation_cache",
    "enable_float64",
    "FileFormatError",
    "MassProperties",
    "boundary_samples",
    "build",
    "load",
    "load_builtin",
    "load_paper_collider",
    "mass_properties",
    "save",
]
