"""A DANO from any density source, as ``dano build`` does it: a watertight mesh (uniform
density), a voxel grid, one of the paper's ``.jld2`` colliders, or a trained field's folder
(``dano train-field``). This is the layer above :mod:`dano.nerf`, so a trained field is a
source like any other.

    from dano.sources import build_from_source
    asset = build_from_source("spot.obj", mass=0.7).asset
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._files import atomic_write
from .asset import DanoAsset
from .asset import build as build_asset
from .errors import DanoError
from .fields import VoxelField, mesh_field
from .io import load_paper_collider, source_kind

#: largest accepted grid resolution (nodes along the longest axis) and sample count
MAX_RESOLUTION = 512  # 1.3e8 nodes: about 5 GB while a signed-distance or marching-cubes grid is built
MAX_SAMPLES = 10_000_000


def check_resolution(resolution: int) -> None:
    """Raises DanoError unless 8 ≤ ``resolution`` ≤ :data:`MAX_RESOLUTION` (with the memory a
    grid of that size would take)."""
    if not 8 <= resolution <= MAX_RESOLUTION:
        raise DanoError(f"--resolution {resolution}: must be 8 to {MAX_RESOLUTION} (a grid of about resolution^3 "
                        f"nodes at ~40 bytes each: {40 * float(resolution) ** 3 / 1e9:.3g} GB)")


@dataclass(frozen=True)
class BuildResult:
    """asset: the DANO; field: the density field it was built from (None for a ``.jld2``,
    whose samples are fixed); calibration: for a trained field with the solid rule, how far
    its surface was moved (keys ``surface_offset`` [m], ``surface_offset_nodes``,
    ``silhouette_area_ratio_before``/``_after``), else empty."""

    asset: DanoAsset
    field: object | None
    calibration: dict = field(default_factory=dict)


def build_from_source(source: str | Path, *, mass: float | None = None, alpha: float | None = None,
                      samples: int = 5000, band: tuple[float, float] | None = None, seed: int = 0,
                      resolution: int = 96, edge_width: float | None = None, normals_mesh: str | Path | None = None,
                      visual_mesh: str | Path | None = None, density_rule: str = "solid",
                      surface_opacity: float = 0.5, calibrate_surface: bool = True, field_scale: float = 1.0,
                      voxels: str | Path | None = None, progress=None) -> BuildResult:
    """Build a DANO from ``source`` (the options of ``dano build``, same names and units).

    source: a mesh (.obj/.stl/.ply/.off/.glb/.gltf, units m), a voxel grid (.npz/.npy), a
    paper collider (.jld2) or a trained field's folder. mass [kg] or alpha (the mass scale):
    at most one. samples: boundary samples N. band: density band of the samples (default
    [0.05, 0.95] × the 99th-percentile density). resolution, edge_width [m]: mesh and field
    sources. normals_mesh, visual_mesh: .jld2 only. density_rule, surface_opacity,
    calibrate_surface, field_scale [m per field unit]: trained fields only
    (docs/fields-from-images.md). voxels: trained fields only: also write the density grid
    there as a voxel ``.npz`` (``density`` (nx, ny, nz), ``bounds`` (2, 3) [m]), loadable
    anywhere, written atomically. progress: optional callback ``(done, total, label)``.
    The asset's name is the source's file stem. Raises DanoError naming the option for an
    option that does not apply to the source or is out of range, FileFormatError for an
    unreadable source, FileNotFoundError for a missing file.
    """
    source = Path(source)
    kind = source_kind(source)
    if not source.is_file() and kind != "field":
        raise FileNotFoundError(f"{source}: no such file")
    if kind != "field" and (voxels is not None or density_rule != "solid" or field_scale != 1.0 or surface_opacity != 0.5
                            or not calibrate_surface):
        raise DanoError("--density-rule, --surface-opacity, --no-calibrate-surface, --field-scale and --voxels "
                        "apply to trained-field folders only")
    check_resolution(resolution)
    if not 1 <= samples <= MAX_SAMPLES:
        raise DanoError(f"--samples {samples}: must be 1 to {MAX_SAMPLES}")
    if kind == "jld2":
        if band is not None or edge_width is not None:
            raise DanoError("--band and --edge-width do not apply to a .jld2 collider (its samples are fixed)")
        if alpha is not None and mass is not None:
            raise DanoError("give either --mass or --alpha, not both")
        asset = load_paper_collider(source, normals_mesh=normals_mesh, visual_mesh=visual_mesh)
        if mass is not None or alpha is not None:
            asset = asset.with_mass(mass if mass is not None else asset.mass * alpha / asset.alpha)
        return BuildResult(asset, None)
    calibration: dict = {}
    if kind == "field":
        from .nerf import load_field
        from .nerf.density import density_grid

        trained, occupancy, meta = load_field(source)
        dens, calibration = density_grid(trained, density_rule, resolution=resolution,
                                         step=meta.get("training", {}).get("sample_step"), scale=field_scale,
                                         surface_opacity=surface_opacity, occupancy=occupancy,
                                         calibrate=calibrate_surface, details=True)
    elif kind == "mesh":
        dens = mesh_field(source, resolution=resolution, edge_width=edge_width,
                          progress=(lambda d, t: progress(d, t, "signed distance")) if progress else None)
    else:
        dens = VoxelField.load(source)
    asset = build_asset(dens, alpha=alpha, mass=mass, num_samples=samples, band=band, seed=seed,
                        name=source.stem, source=str(source.name), progress=progress)
    if voxels is not None:
        atomic_write(Path(voxels), lambda f: np.savez(f, density=np.asarray(dens.values), bounds=dens.node_bounds))
    return BuildResult(asset, dens, calibration or {})
