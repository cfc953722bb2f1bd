"""dano: differentiable simulation of dynamics-augmented neural objects (DANOs).

The flat public API; stages live in submodules: :mod:`dano.fields` (density fields),
:mod:`dano.asset` (mass properties, boundary samples, ``.dano`` files), :mod:`dano.io`
(importers), :mod:`dano.viz` (plots).
"""

from . import _jax_setup  # noqa: F401  (must run before anything imports jax)

__version__ = "0.1.0"

from .asset import DanoAsset, MassProperties, boundary_samples, build, load, mass_properties, save  # noqa: E402
from .data import load_builtin  # noqa: E402
from .errors import DanoError, FileFormatError  # noqa: E402
from .io import load_paper_collider  # noqa: E402

__all__ = [
    "DanoAsset",
    "DanoError",
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
