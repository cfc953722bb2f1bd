"""Density fields φ(x): the geometry of a DANO (paper §IV).

Every field is an immutable JAX pytree with ``density(points) -> (N,)`` and
``bounds() -> (2, 3)``; see :class:`DensityField`. ``to_arrays``/``from_arrays``
turn the built-in fields into flat arrays for the ``.dano`` file.
"""

from __future__ import annotations

import json

import numpy as np

from ..errors import FileFormatError
from .analytic import BoxField, SphereField
from .base import DensityField, evaluate, field_name, smooth_occupancy
from .grid import SdfGridField, VoxelField
from .mesh import mesh_field
from .transform import TransformedField

__all__ = [
    "BoxField",
    "DensityField",
    "SdfGridField",
    "SphereField",
    "TransformedField",
    "VoxelField",
    "evaluate",
    "field_name",
    "from_arrays",
    "mesh_field",
    "smooth_occupancy",
    "to_arrays",
]


def to_arrays(field: DensityField, prefix: str = "field/") -> dict[str, np.ndarray] | None:
    """Flatten a built-in field to ``{name: array}`` (a JSON ``spec`` plus arrays).

    Returns None for fields that cannot be stored (e.g. user-defined ones).
    """
    spec, arrays = _describe(field, prefix)
    if spec is None:
        return None
    arrays[prefix + "spec"] = np.asarray(json.dumps(spec))
    return arrays


def _describe(field, prefix):
    if isinstance(field, SphereField):
        return {"kind": "sphere", "radius": float(field.radius), "edge_width": float(field.edge_width),
                "density_scale": float(field.density_scale), "center": list(map(float, field.center))}, {}
    if isinstance(field, BoxField):
        return {"kind": "box", "half_extents": list(map(float, field.half_extents)),
                "edge_width": float(field.edge_width), "density_scale": float(field.density_scale),
                "center": list(map(float, field.center))}, {}
    if isinstance(field, VoxelField):
        return {"kind": "voxel"}, {prefix + "values": np.asarray(field.values),
                                   prefix + "bounds": field.node_bounds}
    if isinstance(field, SdfGridField):
        return ({"kind": "sdf_grid", "edge_width": float(field.edge_width),
                 "density_scale": float(field.density_scale)},
                {prefix + "sdf": np.asarray(field.sdf), prefix + "bounds": field.bounds()})
    if isinstance(field, TransformedField):
        base_spec, arrays = _describe(field.base, prefix + "base/")
        if base_spec is None:
            return None, {}
        return ({"kind": "transformed", "scale": float(field.scale),
                 "rotation": np.asarray(field.rotation).tolist(), "offset": np.asarray(field.offset).tolist(),
                 "base": base_spec}, arrays)
    return None, {}


def from_arrays(arrays, prefix: str = "field/") -> DensityField | None:
    """Inverse of :func:`to_arrays`; returns None when no field is stored.

    Raises FileFormatError for an unknown kind or missing arrays.
    """
    if prefix + "spec" not in arrays:
        return None
    try:
        spec = json.loads(str(arrays[prefix + "spec"]))
    except json.JSONDecodeError as exc:
        raise FileFormatError(f"stored field spec is not valid JSON ({exc})") from exc
    return _build(spec, arrays, prefix)


def _build(spec, arrays, prefix):
    if not isinstance(spec, dict):
        raise FileFormatError(f"stored field spec is a JSON {type(spec).__name__}, expected an object")
    kind = spec.get("kind")
    try:
        if kind == "sphere":
            return SphereField(spec["radius"], spec["edge_width"], spec["density_scale"], tuple(spec["center"]))
        if kind == "box":
            return BoxField(tuple(spec["half_extents"]), spec["edge_width"], spec["density_scale"],
                            tuple(spec["center"]))
        if kind == "voxel":
            return VoxelField.create(arrays[prefix + "values"], arrays[prefix + "bounds"])
        if kind == "sdf_grid":
            return SdfGridField.create(arrays[prefix + "sdf"], arrays[prefix + "bounds"], spec["edge_width"],
                                       spec["density_scale"])
        if kind == "transformed":
            base = _build(spec["base"], arrays, prefix + "base/")
            return TransformedField.from_matrix(base, spec["scale"], spec["rotation"], spec["offset"])
    except KeyError as exc:
        raise FileFormatError(f"stored field of kind {kind!r} lacks {exc}") from exc
    raise FileFormatError(f"unknown stored field kind {kind!r}")
