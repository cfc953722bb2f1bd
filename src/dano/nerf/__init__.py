"""Density (radiance) fields from posed images: datasets, a hash-grid field, training.

:func:`load_dataset` reads ``transforms.json`` folders and NPZ image sets;
:class:`HashGridField` is a multiresolution hash-grid radiance field in JAX (a
:class:`dano.fields.DensityField` with σ as density); :func:`train` fits it with optax;
:func:`save_field` / :func:`load_field` write and read field directories;
:func:`density_grid` turns a trained field into the density a DANO integrates;
:func:`render_dataset` renders training views of a mesh with MuJoCo.
"""

from .checkpoint import load_field, read_meta, save_field
from .data import Dataset, load_dataset
from .density import DENSITY_RULES, density_grid
from .field import FieldConfig, HashGridField
from .synthetic import render_dataset
from .train import TrainConfig, TrainResult, evaluate, render_options, train

__all__ = [
    "DENSITY_RULES",
    "Dataset",
    "FieldConfig",
    "HashGridField",
    "TrainConfig",
    "TrainResult",
    "evaluate",
    "density_grid",
    "load_dataset",
    "load_field",
    "read_meta",
    "render_dataset",
    "render_options",
    "save_field",
    "train",
]
