"""Assets that ship inside the package (no downloads, no files from outside).

* ``bunny``: the paper's NeRF-derived Stanford-bunny collider (``bunny.jld2`` of
  Le Cleac'h et al., Dojo.jl DANO branch, MIT licence, see ``NOTICE.md``),
  imported with :func:`dano.io.load_paper_collider`; paper scene units; its visual mesh
  is the paper's level-set mesh (iso 105) decimated to 3000 faces.
* ``bunny_lowpoly``: a queryable DANO (signed-distance field) built from the watertight
  low-poly Stanford bunny of pybullet_data (zlib licence), upright, 0.72 units tall,
  mass 3.2; used where DANOs touch each other.
* ``bluesoap``: the paper's collider of a real bar of soap (``bluesoap.jld2``, MIT), its
  zero gradients replaced by normals from the paper's level-set mesh.
* ``soap_pose_traj.csv`` (:func:`builtin_file`): the soap sliding on a table, tracked by
  the paper's authors in a real video at 120 frames/s (7 rows x, y, z, qw, qx, qy, qz; MIT).
"""

from __future__ import annotations

from importlib import resources

from ..asset import load
from ..errors import DanoError

BUILTIN_ASSETS = ("bunny", "bunny_lowpoly", "bluesoap")


def builtin_path(name: str):
    """Path of a built-in ``.dano`` asset. Raises DanoError for an unknown name."""
    if name not in BUILTIN_ASSETS:
        raise DanoError(f"unknown built-in asset {name!r}; available: {', '.join(BUILTIN_ASSETS)}")
    return resources.files(__name__) / f"{name}.dano"


def builtin_file(name: str):
    """A data file shipped with dano (e.g. ``soap_pose_traj.csv``), as a Traversable."""
    path = resources.files(__name__) / name
    if not path.is_file():
        raise DanoError(f"no built-in data file {name!r}")
    return path


def load_builtin(name: str = "bunny"):
    """Load a built-in asset (default: the paper bunny) as a :class:`~dano.asset.DanoAsset`."""
    with resources.as_file(builtin_path(name)) as p:
        return load(p)


def load_asset(source: str):
    """A DANO asset from ``"FILE.dano"`` or ``"builtin:NAME"`` (:data:`BUILTIN_ASSETS`), as the
    command line's options name them. Raises DanoError / FileFormatError naming the file."""
    return load_builtin(source.split(":", 1)[1]) if source.startswith("builtin:") else load(source)
