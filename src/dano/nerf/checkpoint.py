"""Field directories: a trained field saved so that it can be loaded, resumed and built.

A field directory holds ``field.json`` (format name and version, architecture, object
box [m], frame, training state) written last, ``field.npz`` (parameters and occupancy
grid) and ``optimizer.npz`` (Adam's moments, for resuming). Every file is written
atomically; ``field.json`` names the arrays it expects, so a directory whose writing was
interrupted reads as an error, never as a different field.
"""

from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from .._config import typed_table
from .._files import atomic_write, read_npz
from .._version import __version__
from ..errors import FileFormatError
from ..render.volume import OccupancyGrid
from .field import FieldConfig, HashGridField

FORMAT = "dano-field"
VERSION = 1


def _leaves(tree) -> dict[str, np.ndarray]:
    return {f"{i:04d}": np.asarray(x) for i, x in enumerate(jax.tree_util.tree_leaves(tree))}


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    atomic_write(path, lambda f: np.savez(f, **arrays))


def save_field(directory: str | Path, field: HashGridField, occupancy: OccupancyGrid, info: dict,
               optimizer_state=None) -> Path:
    """Write ``field`` (and ``optimizer_state`` for resuming) to ``directory``.

    info: JSON-able training state (step, elapsed seconds, data source, PSNR …), stored
    under ``"training"``. Returns the directory.
    """
    directory = Path(directory)
    arrays = {"params/" + k: v for k, v in _leaves(field.params).items()}
    arrays["occupancy"] = np.asarray(occupancy.density)
    _write_npz(directory / "field.npz", arrays)
    if optimizer_state is not None:
        _write_npz(directory / "optimizer.npz", _leaves(optimizer_state))
    meta = {
        "format": FORMAT,
        "version": VERSION,
        "dano_version": __version__,
        "kind": "hash-grid radiance field",
        "config": asdict(field.config),
        "bounds": field.bounds().tolist(),
        "frame": "object",
        "units": "m (positions), 1/m (density sigma)",
        "occupancy_threshold": occupancy.threshold,
        "arrays": sorted(arrays),
        "optimizer": optimizer_state is not None,
        "training": info,
    }
    atomic_write(directory / "field.json", lambda f: f.write((json.dumps(meta, indent=2) + "\n").encode()))
    return directory


def read_meta(directory: str | Path) -> dict:
    """The checked ``field.json`` of a field directory.

    Raises FileFormatError if the directory has none, or it is of another format or version.
    """
    path = Path(directory) / "field.json"
    if not path.exists():
        raise FileFormatError(f"{Path(directory)}: not a field directory (no field.json; train one with "
                              "`dano train-field`)")
    try:
        meta = json.loads(path.read_text())
    except Exception as exc:
        raise FileFormatError(f"{path}: cannot read JSON ({exc})") from exc
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        found = meta.get("format") if isinstance(meta, dict) else None
        raise FileFormatError(f"{path}: not a dano field (format {found!r})")
    if meta.get("version") != VERSION:
        raise FileFormatError(f"{path}: field format version {meta.get('version')!r} (written by dano "
                              f"{meta.get('dano_version', '?')}); this dano reads version {VERSION}")
    return meta


def load_field(directory: str | Path) -> tuple[HashGridField, OccupancyGrid, dict]:
    """Read a field directory: ``(field, occupancy grid, field.json contents)``.

    Raises FileFormatError naming the file for a missing, truncated or inconsistent directory
    or one written by another format version.
    """
    directory = Path(directory)
    meta = read_meta(directory)
    try:
        # fields saved before sigma_unit existed had σ = exp(h)
        config = typed_table({"sigma_unit": 1.0, **meta["config"]}, FieldConfig, "config")
        template = HashGridField.create(meta["bounds"], config)
    except Exception as exc:
        raise FileFormatError(f"{directory / 'field.json'}: bad field description ({exc})") from exc
    arrays = _read_npz(directory / "field.npz", meta.get("arrays"))
    params = _restore(template.params, {k[len("params/"):]: v for k, v in arrays.items() if k.startswith("params/")},
                      directory / "field.npz")
    field = HashGridField(params, template.box, config)
    occ = OccupancyGrid.create(meta["bounds"], arrays["occupancy"].shape[0], float(meta["occupancy_threshold"]))
    density = jnp.asarray(arrays["occupancy"], jnp.float32)
    cutoff = jnp.minimum(occ.threshold, jnp.mean(density))
    occupancy = OccupancyGrid(density, occ.lower, occ.upper, cutoff, occ.threshold)
    return field, occupancy, meta


def load_optimizer_state(directory: str | Path, template):
    """Adam's state saved beside a field, shaped like ``template``. Raises FileFormatError."""
    path = Path(directory) / "optimizer.npz"
    return _restore(template, _read_npz(path, None), path)


def _read_npz(path: Path, expected) -> dict[str, np.ndarray]:
    arrays = read_npz(path)
    if expected is not None and sorted(arrays) != sorted(expected):
        raise FileFormatError(f"{path}: holds arrays other than field.json lists (an interrupted write?)")
    return arrays


def _restore(template, arrays: dict[str, np.ndarray], path: Path):
    leaves, treedef = jax.tree_util.tree_flatten(template)
    if len(arrays) != len(leaves):
        raise FileFormatError(f"{path}: {len(arrays)} arrays, expected {len(leaves)}")
    out = []
    for i, leaf in enumerate(leaves):
        value = arrays[f"{i:04d}"]
        if value.shape != np.shape(leaf):
            raise FileFormatError(f"{path}: array {i} has shape {value.shape}, expected {np.shape(leaf)}")
        if np.issubdtype(value.dtype, np.floating) and not np.all(np.isfinite(value)):
            raise FileFormatError(f"{path}: array {i} holds NaN or inf")
        out.append(jnp.asarray(value, dtype=jnp.asarray(leaf).dtype))
    return jax.tree_util.tree_unflatten(treedef, out)
