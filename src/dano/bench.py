"""Benchmarks behind ``dano bench``: wall times as JSON (medians of repeats; the first,
compiling run reported separately). Machines are noisy: compare ratios measured in one run."""

from __future__ import annotations

import platform
import statistics
import time
from typing import Callable

import jax
import numpy as np


def _time(fn: Callable[[], object], repeats: int) -> dict:
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return {"first_s": first, "median_s": statistics.median(times), "min_s": min(times), "repeats": repeats}


def bench_build(repeats: int = 3, mesh_path=None) -> dict:
    """Time to build a 5000-sample asset from an analytic sphere and from a mesh field.

    mesh_path: a watertight mesh (default: a trimesh icosphere, subdivision 4, so the
    benchmark needs no outside file). Reports the signed-distance grid and the asset
    build (mass properties + samples + visual mesh) separately.
    """
    import trimesh

    from .asset import build
    from .fields import SphereField, mesh_field

    results = {}
    sphere = SphereField(0.5)
    results["build_analytic_sphere_5000"] = _time(lambda: build(sphere, num_samples=5000), repeats)
    mesh = trimesh.load(mesh_path, force="mesh") if mesh_path else trimesh.creation.icosphere(4, radius=0.5)
    results["mesh_field_sdf_96"] = _time(lambda: mesh_field(mesh), repeats)
    field = mesh_field(mesh)
    results["build_mesh_field_5000"] = _time(lambda: build(field, num_samples=5000), repeats)
    results["mesh"] = str(mesh_path) if mesh_path else "icosphere(subdivisions=4)"
    return results


def environment() -> dict:
    from . import __version__

    return {
        "dano": __version__,
        "jax": jax.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "machine": platform.machine(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }


SUITES = {"build": bench_build}


def run(suites: list[str] | None = None, repeats: int = 3) -> dict:
    """Run the named suites (default all) and return one JSON-able dict."""
    names = suites or list(SUITES)
    return {"environment": environment(), **{n: SUITES[n](repeats=repeats) for n in names}}
