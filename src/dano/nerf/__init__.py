"""Density (radiance) fields from posed images: datasets, a hash-grid field, training.

:func:`load_dataset` reads ``transforms.json`` folders and NPZ image sets;
:class:`HashGridField` is a multiresolution hash-grid radiance field in JAX (a
:class:`dano.fields.DensityField` with σ as density); :func:`train` fits it with optax;
:func:`save_field` / :func:`load_field` write and read field directories.
"""

from .checkpoint import load_field, read_meta, save_field
from .data import Dataset, load_dataset
from .field import FieldConfig, HashGridField
from .train import TrainConfig, TrainResult, evaluate, render_options, train

__all__ = [
    "Dataset",
    "FieldConfig",
    "HashGridField",
    "TrainConfig",
    "TrainResult",
    "evaluate",
    "load_dataset",
    "load_field",
    "read_meta",
    "render_options",
    "save_field",
    "train",
]
