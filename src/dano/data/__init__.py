"""Assets that ship inside the package (no downloads, no files from outside).

* ``bunny``: the paper's NeRF-derived Stanford-bunny collider (``bunny.jld2`` of
  Le Cleac'h et al., Dojo.jl DANO branch, MIT licence, see ``NOTICE.md``),
  imported with :func:`dano.io.load_paper_collider`; paper scene units.
"""

from __future__ import annotations

from importlib import resources

from ..errors import DanoError

BUILTIN_ASSETS = ("bunny",)


def builtin_path(name: str):
    """Path of a built-in ``.dano`` asset. Raises DanoError for an unknown name."""
    if name not in BUILTIN_ASSETS:
        raise DanoError(f"unknown built-in asset {name!r}; available: {', '.join(BUILTIN_ASSETS)}")
    return resources.files(__name__) / f"{name}.dano"


def load_builtin(name: str = "bunny"):
    """Load a built-in asset (default: the paper bunny) as a :class:`~dano.asset.DanoAsset`."""
    from ..asset import load

    with resources.as_file(builtin_path(name)) as p:
        return load(p)
