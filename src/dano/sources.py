"""A DANO from any density source, as ``dano build`` does it: a watertight mesh (uniform
density), a voxel grid, one of the paper's ``.jld2`` colliders, or a trained field's folder
(``dano train-field``). This is the layer above :mod:`dano.nerf`, so a trained field is a
source like any other.

    from dano.sources import build_from_source
    asset = build_from_source("spot.obj", mass=0.7).asset
"""

from __future__ import annotations

import dataclasses
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from ._files import atomic_write
from .asset import DanoAsset, save
from .asset import build as build_asset
from .errors import DanoError
from .fields import VoxelField, mesh_field
from .fields.mesh import load_mesh
from .fields.base import MAX_RESOLUTION, check_resolution  # noqa: F401  (re-exported)
from .io import load_paper_collider, source_kind

#: largest accepted sample count
MAX_SAMPLES = 10_000_000

#: ``--up`` choices: the source's axis that points up -> the rotation (3, 3) taking it to +z
#: (y: +90° about x, the usual y-up to z-up conversion, so the source's -z faces +y)
UP_ROTATIONS = {
    "z": np.eye(3),
    "y": np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]]),
    "x": np.array([[0.0, 0, -1], [0, 1, 0], [1, 0, 0]]),
    "-z": np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]]),
    "-y": np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]]),
    "-x": np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),
}


def up_rotation(up: str) -> np.ndarray:
    """The rotation (3, 3) that turns the source axis ``up`` (x, y, z, -x, -y, -z; a leading +
    allowed) into +z. Raises DanoError naming --up for anything else."""
    key = str(up).strip().lower().lstrip("+")
    if key not in UP_ROTATIONS:
        raise DanoError(f"--up {up!r}: must be the source's axis that points up: {', '.join(UP_ROTATIONS)}")
    return UP_ROTATIONS[key]


def rotate_grid(field: VoxelField, rotation: np.ndarray) -> VoxelField:
    """``field`` turned by an axis-aligned ``rotation`` (3, 3), a signed permutation (e.g.
    :func:`up_rotation`): the nodes are transposed and flipped, exactly (no resampling)."""
    R = np.rint(np.asarray(rotation)).astype(int)
    values, lower, upper = np.asarray(field.values), np.asarray(field.lower), np.asarray(field.upper)
    src = [int(np.flatnonzero(R[i])[0]) for i in range(3)]  # new axis i is source axis src[i] times R[i, src[i]]
    out = np.transpose(values, src)
    lo, hi = np.empty(3), np.empty(3)
    for i, j in enumerate(src):
        if R[i, j] > 0:
            lo[i], hi[i] = lower[j], upper[j]
        else:
            lo[i], hi[i] = -upper[j], -lower[j]
            out = np.flip(out, axis=i)
    return VoxelField.create(np.ascontiguousarray(out), np.stack([lo, hi])).named(field.name)


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
                      voxels: str | Path | None = None, scale: float | None = None, size: float | None = None,
                      up: str = "z", progress=None) -> BuildResult:
    """Build a DANO from ``source`` (the options of ``dano build``, same names and units).

    source: a mesh (.obj/.stl/.ply/.off/.glb/.gltf, units m), a voxel grid (.npz/.npy), a
    paper collider (.jld2) or a trained field's folder. mass [kg] or alpha (the mass scale):
    at most one. samples: boundary samples N. band: density band of the samples (default
    [0.05, 0.95] × the 99th-percentile density). resolution, edge_width [m]: mesh and field
    sources. normals_mesh, visual_mesh: .jld2 only. density_rule, surface_opacity,
    calibrate_surface, field_scale [m per field unit]: trained fields only
    (docs/fields-from-images.md). voxels: trained fields only: also write the density grid
    there as a voxel ``.npz`` (``density`` (nx, ny, nz), ``bounds`` (2, 3) [m]), loadable
    anywhere, written atomically. scale: multiply the source's lengths by this (e.g. 0.001 for
    a mesh in millimetres); size: scale the source so that its longest bounding-box extent is
    this [m] (meshes: the mesh's box; grids: the box of the nodes at half the peak density);
    at most one of the two, for meshes, voxel grids and trained fields. up: the source's axis
    that points up (x, y, z, -x, -y, -z; default z, the source as it is): the source is turned
    so that this axis becomes +z (dano's up), e.g. "y" for a mesh written y-up, as many .obj
    files are (Spot, the Stanford bunny): +90° about x (:data:`UP_ROTATIONS`); meshes, voxel grids and
    trained fields. progress: optional callback ``(done, total, label)``.
    The asset's name is the source's file stem. Raises DanoError naming the option for an
    option that does not apply to the source or is out of range, FileFormatError for an
    unreadable source, FileNotFoundError for a missing file.
    """
    source = Path(source)
    kind = source_kind(source)
    if scale is not None and size is not None:
        raise DanoError("give either --scale or --size, not both")
    if field_scale != 1.0 and (scale is not None or size is not None):  # (they would multiply)
        raise DanoError("give either --field-scale or --scale/--size, not both (--field-scale is --scale for a "
                        "trained field: metres per field unit)")
    for opt, v in (("scale", scale), ("size", size)):
        if v is not None and not 0 < v < np.inf:
            raise DanoError(f"--{opt} must be a finite positive number, got {v}")
    if not source.is_file() and kind != "field":
        raise FileNotFoundError(f"{source}: no such file")
    if kind != "field" and (voxels is not None or density_rule != "solid" or field_scale != 1.0 or surface_opacity != 0.5
                            or not calibrate_surface):
        raise DanoError("--density-rule, --surface-opacity, --no-calibrate-surface, --field-scale and --voxels "
                        "apply to trained-field folders only")
    rotation = up_rotation(up)
    check_resolution(resolution)
    if not 1 <= samples <= MAX_SAMPLES:
        raise DanoError(f"--samples {samples}: must be 1 to {MAX_SAMPLES}")
    if kind == "jld2":
        turned = rotation is not UP_ROTATIONS["z"]
        if band is not None or edge_width is not None or scale is not None or size is not None or turned:
            raise DanoError("--band, --edge-width, --scale, --size and --up do not apply to a .jld2 collider (its "
                            "samples are fixed)")
        if alpha is not None and mass is not None:
            raise DanoError("give either --mass or --alpha, not both")
        asset = load_paper_collider(source, normals_mesh=normals_mesh, visual_mesh=visual_mesh)
        if mass is not None or alpha is not None:
            asset = asset.with_mass(mass if mass is not None else asset.mass * alpha / asset.alpha)
        return BuildResult(asset, None)
    calibration: dict = {}
    if kind == "field":
        # the NeRF stage (optax, the renderer) loads only for a trained field, not for a mesh build
        from .nerf import load_field
        from .nerf.density import density_grid

        trained, occupancy, meta = load_field(source)
        dens, calibration = density_grid(trained, density_rule, resolution=resolution,
                                         step=meta.get("training", {}).get("sample_step"), scale=field_scale,
                                         surface_opacity=surface_opacity, occupancy=occupancy,
                                         calibrate=calibrate_surface, details=True)
    elif kind == "mesh":
        mesh = load_mesh(source)
        if scale is not None or size is not None:
            mesh.apply_scale(scale if scale is not None else size / float(np.max(mesh.extents)))
        if rotation is not UP_ROTATIONS["z"]:
            transform = np.eye(4)
            transform[:3, :3] = rotation
            mesh.apply_transform(transform)
        dens = mesh_field(mesh, resolution=resolution, edge_width=edge_width,
                          progress=(lambda d, t: progress(d, t, "signed distance")) if progress else None)
    else:
        dens = VoxelField.load(source)
    if kind != "mesh" and (scale is not None or size is not None):
        factor = scale if scale is not None else size / occupied_extent(dens)
        dens = VoxelField.create(np.asarray(dens.values), np.stack([np.asarray(dens.lower), np.asarray(dens.upper)])
                                 * factor)
        if "surface_offset" in calibration:  # [m] of the object as built, as the grid
            calibration = {**calibration, "surface_offset": calibration["surface_offset"] * factor}
    if kind != "mesh" and rotation is not UP_ROTATIONS["z"]:
        dens = rotate_grid(dens, rotation)
    asset = build_asset(dens, alpha=alpha, mass=mass, num_samples=samples, band=band, seed=seed,
                        name=source.stem, source=str(source.name), progress=progress)
    if voxels is not None:
        atomic_write(Path(voxels), lambda f: np.savez(f, density=np.asarray(dens.values), bounds=dens.node_bounds))
    return BuildResult(asset, dens, calibration or {})


@dataclass(frozen=True)
class BuildConfig:
    """Build a DANO asset (.dano) from a density source."""

    source: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")]
    """a watertight mesh (.obj/.stl/.ply/.off, read as uniform density, units m), a voxel grid (.npz with
    arrays 'density' (nx, ny, nz) and 'bounds' (2, 3) [m]), a paper collider (.jld2) or a trained field's
    folder (written by dano train-field; the options marked 'field folders:')."""
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))]
    """the .dano file to write (written atomically)."""
    mass: float | None = None
    """total mass [kg]; sets the mass scale alpha. Not with --alpha."""
    alpha: float | None = None
    """the mass scale alpha (mass = alpha * integral of density). Default 1."""
    samples: int = 5000
    """number of boundary samples N."""
    band: tuple[float, float] | None = None
    """density band LO HI of the boundary samples; default [0.05, 0.95] x 99th-percentile density."""
    seed: int = 0
    """random seed (samples and quasi-Monte Carlo integration are deterministic given it)."""
    resolution: int = 96
    """mesh sources: signed-distance grid nodes along the longest axis."""
    edge_width: float | None = None
    """mesh sources: width of the smooth surface edge [m] (default a quarter grid cell)."""
    normals_mesh: Path | None = None
    """.jld2 sources: level-set mesh to recompute degenerate (zero) normals from."""
    visual_mesh: Path | None = None
    """.jld2 sources: mesh (collider frame) stored for rendering."""
    density_rule: str = "solid"
    """field folders: how sigma becomes density: solid (the seen surface filled, uniform inside), occupancy (1
    - exp(-sigma*step)) or sigma (the paper's); see docs/fields-from-images.md."""
    surface_opacity: float = 0.5
    """field folders, solid rule: the surface is where the opacity accumulated from outside reaches this (0.5:
    a render's median depth)."""
    calibrate_surface: bool = True
    """field folders, solid rule: then move that surface along its normal so that the solid's silhouettes cover
    as many pixels as the field's own renders from 12 views around it (a soft field's median-depth surface
    lies inside the object)."""
    field_scale: float = 1.0
    """field folders: metres per field unit (1 for fields trained on `dano render-dataset` views)."""
    voxels: Path | None = None
    """field folders: also write the density grid as a voxel .npz (density, bounds), loadable anywhere."""
    scale: float | None = None
    """multiply the source's lengths by this (meshes, voxel grids, trained fields), e.g. 0.001 for a mesh in
    millimetres. Not with --size."""
    size: float | None = None
    """scale the source so that its longest extent is this [m] (meshes: the mesh's bounding box; grids: the
    box of the nodes at half the peak density). Not with --scale."""
    up: Annotated[str, tyro.conf.arg(metavar="AXIS")] = "z"
    """the source's axis that points up: x, y, z, -x, -y or -z; the DANO is turned so that it becomes +z (dano's
    up). y for a mesh written y-up, as many .obj files are (+90 degrees about x)."""
    name: str | None = None
    """the object's name in scenes, pairs (NAME/ground) and options such as --qvel NAME=... (default: the
    source's file or folder name, e.g. spot for spot.obj)."""
    quiet: bool = False
    """no progress bar."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object: the asset's summary (as dano inspect --json), the file written ("file"), the
    surface calibration of a trained field ("calibration", or null), "warnings" (a list: an implausible
    mean density, as dano inspect warns), wall_time_s and compile_time_s."""

    def __post_init__(self):
        up_rotation(self.up)
        check_resolution(self.resolution)
        if not 1 <= self.samples <= MAX_SAMPLES:
            raise DanoError(f"--samples {self.samples}: must be 1 to {MAX_SAMPLES}")
        if self.name is not None and not re.fullmatch(r"[A-Za-z0-9_.-]+", self.name):
            raise DanoError(f"--name {self.name!r}: letters, digits, '_', '.' and '-' only (it names the object "
                            "in pairs such as NAME/ground and in options such as --qvel NAME=...)")
        if Path(self.out).is_dir():  # (checked now, not when the finished asset is written)
            raise DanoError(f"-o {self.out}: is a folder; give the file to write, e.g. {Path(self.out) / 'object.dano'}")
        for option in ("mass", "alpha", "size", "scale"):  # (checked now, before the source is read)
            value = getattr(self, option)
            if value is not None and not (math.isfinite(value) and value > 0):
                raise DanoError(f"--{option} must be a finite positive number, got {value:g}")


def build_file(config: BuildConfig, progress=None) -> BuildResult:
    """``dano build``: :func:`build_from_source` with ``config``'s options, the asset saved to
    ``config.out`` (atomically; and the voxel grid to ``config.voxels`` for a trained field)."""
    options = {f: getattr(config, f) for f in ("mass", "alpha", "samples", "band", "seed", "resolution", "edge_width",
                                               "normals_mesh", "visual_mesh", "density_rule", "surface_opacity",
                                               "calibrate_surface", "field_scale", "voxels", "scale", "size",
                                               "up")}
    result = build_from_source(config.source, **options, progress=progress)
    if config.name is not None:
        result = dataclasses.replace(result, asset=dataclasses.replace(result.asset, name=config.name))
    save(result.asset, config.out)
    return result


def occupied_extent(field: VoxelField) -> float:
    """The longest extent [m] of the box holding the grid nodes whose density is at least half
    the peak (the object, without the grid's empty margin). Raises DanoError for an empty grid."""
    values = np.asarray(field.values)
    peak = float(values.max())
    if not peak > 0:
        raise DanoError("the density grid is empty (all zero): it has no size")
    idx = np.argwhere(values >= 0.5 * peak)
    cell = (np.asarray(field.upper) - np.asarray(field.lower)) / np.maximum(np.array(values.shape) - 1, 1)
    return float(np.max((idx.max(0) - idx.min(0)) * cell))
