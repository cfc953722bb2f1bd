"""``dano export`` as a library call: :class:`ExportConfig` (the verb's options) and
:func:`export_command`. Kept apart from :mod:`dano.io.exporters` so that ``import dano``
does not load the command line's parser library."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro

from ..data import load_asset
from ..errors import DanoError
from ..fields.base import check_resolution
from ..fields.mesh import load_mesh
from .exporters import EXPORT_SUFFIXES, Decomposition, friction_note, body_meshes, export, read_contact_params


@dataclass(frozen=True)
class ExportConfig:
    """Export a DANO as a MuJoCo MJCF (.xml) or URDF (.urdf) body: its mass, centre of mass and full inertia,
    its visual mesh and collision geometry."""

    file: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="FILE.dano")]
    """the .dano file (or builtin:NAME)."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """OUT.xml (MJCF, one file, meshes inline) or OUT.urdf (plus OUT_meshes/ with OBJ files). The body frame is
    the DANO's (object axes, origin at the centre of mass)."""
    collision: Literal["hull", "decomposition", "none"] = "hull"
    """'hull' (convex hull of a level set), 'decomposition' (CoACD approximate convex decomposition of it) or
    'none'."""
    level: float | None = None
    """density of the level set to make collision geometry from (needs a stored field); default the asset's
    visual mesh."""
    mesh: Path | None = None
    """a level-set mesh (object frame) to use instead, e.g. the paper's bluesoap_level_70.stl."""
    resolution: int = 96
    """marching-cubes nodes along the longest axis for --level."""
    threshold: float = 0.1
    """CoACD concavity threshold (smaller: more, tighter pieces; slower)."""
    max_pieces: int = -1
    """CoACD: merge down to at most this many pieces (-1: no limit)."""
    name: str | None = None
    """body/link name (default the asset's)."""
    params: Path | None = None
    """identified contact parameters to carry: a `dano sysid` result.json (or a JSON table of names to
    values); MJCF collision geoms get friction = sliding, torsional, rolling friction and priority 1 (their
    friction wins over a floor's), and a comment says what MuJoCo cannot carry (spring, damper, drags) and that
    condim 3 leaves the torsional and rolling coefficients unused."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print a JSON summary (path, collision, pieces, mass, inertia) to stdout."""

    def __post_init__(self):
        if Path(self.out).suffix.lower() not in EXPORT_SUFFIXES:  # before any (possibly long) decomposition
            raise DanoError(f"-o {self.out}: unknown export format {Path(self.out).suffix!r}; use .xml (MJCF) or "
                            ".urdf (URDF)")
        if not 0 < self.threshold < float("inf"):
            raise DanoError(f"--threshold must be a positive number, got {self.threshold}")
        check_resolution(self.resolution)
        if self.mesh is not None and self.level is not None:
            raise DanoError("give either --level or --mesh, not both")


def export_command(config: ExportConfig) -> dict:
    """``dano export``: the asset's body with its collision meshes (:func:`body_meshes`)
    written as MJCF or URDF (:func:`export`). Returns the summary: ``path``, ``format``,
    ``collision``, ``collision_source``, ``pieces``, ``mass`` [kg], ``inertia`` (3, 3) [kg m²]."""
    asset = load_asset(config.file)
    given = load_mesh(config.mesh, require_watertight=False) if config.mesh is not None else None
    meshes = body_meshes(asset, config.collision, level=config.level, mesh=given, resolution=config.resolution,
                         decomposition=Decomposition(threshold=config.threshold, max_pieces=config.max_pieces))
    contact = read_contact_params(config.params) if config.params is not None else None
    export(asset, config.out, meshes=meshes, name=config.name, contact=contact)
    return {"friction": None if contact is None else [float(x) for x in friction_note(contact)[0].split()],"path": str(config.out), "format": "mjcf" if Path(config.out).suffix.lower() == ".xml" else "urdf",
            "collision": config.collision, "collision_source": meshes.source, "pieces": len(meshes.collision),
            "mass": asset.mass, "inertia": asset.inertia.tolist()}
