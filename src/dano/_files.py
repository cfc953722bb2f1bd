"""Atomic file output: a result appears complete or not at all (bad input loses nothing)."""

from __future__ import annotations

import os
import shutil
import tempfile
import zipfile
from contextlib import contextmanager
from pathlib import Path
from typing import Any, Callable, Iterator

import numpy as np

from .errors import DanoError, FileFormatError


#: the mesh files ``dano build`` reads (trimesh's formats), units m
MESH_SUFFIXES = (".obj", ".stl", ".ply", ".off", ".glb", ".gltf")


def source_kind(path: str | Path) -> str:
    """What ``dano build`` reads ``path`` as: 'mesh', 'voxel', 'jld2' from the file suffix,
    or 'field' for a folder (a field directory written by ``dano train-field``); raises
    FileFormatError otherwise."""
    if Path(path).is_dir():
        return "field"
    suffix = Path(path).suffix.lower()
    if suffix in MESH_SUFFIXES:
        return "mesh"
    if suffix in (".npy", ".npz"):
        return "voxel"
    if suffix == ".jld2":
        return "jld2"
    raise FileFormatError(
        f"{path}: unknown source type {suffix!r}; expected a mesh ({', '.join(MESH_SUFFIXES)}), "
        "a voxel grid (.npy/.npz), a paper collider (.jld2) or a trained field's folder"
    )


@contextmanager
def atomic_path(path: str | Path) -> Iterator[Path]:
    """Yield a temporary path beside ``path`` (same suffix, so writers that pick a format
    from it still work); on success it is renamed to ``path`` with the usual permissions,
    on any error it is removed and ``path`` is left untouched."""
    path = Path(path)
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=path.suffix or ".tmp", dir=path.parent)
        os.close(fd)
    except OSError as exc:
        raise _about_output(exc, path) from exc
    try:
        yield Path(tmp)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)
        os.replace(tmp, path)
    except BaseException as exc:
        if os.path.exists(tmp):
            os.unlink(tmp)
        if isinstance(exc, OSError) and exc.filename in (tmp, str(tmp)):
            raise _about_output(exc, path) from exc
        raise


@contextmanager
def atomic_dir(out_dir: str | Path) -> Iterator[Path]:
    """Yield a temporary folder beside ``out_dir``; on success it becomes ``out_dir`` (usual
    permissions; an empty ``out_dir`` is replaced), on any error it is removed. Raises
    DanoError up front if ``out_dir`` exists and is not an empty folder."""
    out_dir = Path(out_dir)
    if out_dir.exists() and (not out_dir.is_dir() or any(out_dir.iterdir())):
        raise DanoError(f"{out_dir}: exists and is not an empty folder; choose a new output folder")
    out_dir.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.", dir=out_dir.parent))
    try:
        yield tmp
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o777 & ~umask)
        if out_dir.exists():
            out_dir.rmdir()
        os.replace(tmp, out_dir)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise


def _about_output(exc: OSError, path: Path) -> OSError:
    """The same error, naming the output the user asked for rather than a temporary file."""
    other = Path(str(exc.filename)) if exc.filename else None
    temporary = other is not None and other.parent == path.parent and other.name.startswith(f".{path.stem}.")
    where = f": {other}" if other is not None and other != path and not temporary else ""
    return OSError(exc.errno, f"cannot write ({exc.strerror or exc}{where})", str(path))


def atomic_write(path: str | Path, writer: Callable[[Any], None]) -> None:
    """Call ``writer(binary file object)`` and atomically publish the result at ``path``."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        writer(f)


def read_npz(path: str | Path, required=(), what: str = "") -> dict:
    """All arrays of an ``.npz`` file (no pickles) as ``{name: array}``.

    Raises FileFormatError naming ``path`` if it cannot be read (``what`` says what it was
    meant to be) or lacks any of the ``required`` arrays.
    """
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            arrays = {k: z[k] for k in z.files}
    except Exception as exc:
        # (NumPy reads a file that is not a zip archive as a pickle, and says so: misleading here)
        reason = exc if not path.is_file() or zipfile.is_zipfile(path) else "not an npz archive"
        raise FileFormatError(f"{path}: cannot read{' ' + what if what else ''} ({reason})") from exc
    missing = sorted(set(required) - set(arrays))
    if missing:
        raise FileFormatError(f"{path}: missing arrays {missing}; expected {', '.join(required)}")
    return arrays


def json_safe(obj, where: str = "", replace: Callable[[float], Any] = lambda x: None) -> tuple[Any, list[str]]:
    """(a copy of ``obj`` (dicts, lists, tuples as lists) with each non-finite float x as
    ``replace(x)``, None by default, the keys where that happened): NaN and infinity are not
    JSON, and a NaN standard error must not pass silently."""
    import math

    found: list[str] = []

    def clean(x, key):
        if isinstance(x, float) and not math.isfinite(x):
            found.append(key)
            return replace(x)
        if isinstance(x, dict):
            return {k: clean(v, f"{key}.{k}" if key else str(k)) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v, f"{key}[{i}]") for i, v in enumerate(x)]
        return x

    return clean(obj, where), found


def config_json(value) -> str:
    """``value`` (a resolved configuration: a dict of settings) as strict JSON text, indented,
    with a trailing newline: an infinite float is written as the string ``"inf"`` or
    ``"-inf"``, which :func:`dano._config.typed` reads back as the number (Python's
    ``Infinity`` is not JSON, and other tools refuse it); a NaN, which a configuration's
    checks refuse, as null."""
    import json

    words = lambda x: None if x != x else ("inf" if x > 0 else "-inf")  # noqa: E731
    return json.dumps(json_safe(value, replace=words)[0], indent=2, allow_nan=False, default=str) + "\n"


def check_new_folder(path: str | Path) -> None:
    """Raises DanoError unless ``path`` does not exist or is an empty folder (an output folder
    a command will fill: nothing of the user's is overwritten or mixed in)."""
    out = Path(path)
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise DanoError(f"{out}: exists and is not an empty folder; choose a new output folder")
