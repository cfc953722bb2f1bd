import os
from pathlib import Path

# One XLA CPU thread, as the dano command line uses (must be set before JAX starts).
os.environ.setdefault("NPROC", "1")

import numpy as np  # noqa: E402
import pytest  # noqa: E402

import dano  # noqa: E402,F401  (sets up JAX before any test imports it)

dano.enable_float64()  # physics and gradient tests compare in float64
dano.enable_compilation_cache()

SHARED = Path(__file__).resolve().parents[1] / ".." / "shared" / "data"


@pytest.fixture(scope="session")
def shared() -> Path:
    if not SHARED.is_dir():
        pytest.fail(f"test data folder {SHARED} is missing (it sits beside the project root)")
    return SHARED.resolve()


@pytest.fixture(scope="session")
def paper_bunny(shared):
    from dano.io import load_paper_collider

    return load_paper_collider(shared / "dano" / "bunny.jld2")


def sphere_voxels(path: Path, radius: float = 0.3, n: int = 33, value: float = 1.0) -> Path:
    """A voxel .npz of a soft sphere, for tests."""
    ax = np.linspace(-0.5, 0.5, n)
    X, Y, Z = np.meshgrid(ax, ax, ax, indexing="ij")
    r = np.sqrt(X**2 + Y**2 + Z**2)
    dens = value / (1 + np.exp((r - radius) / 0.02))
    np.savez(path, density=dens, bounds=np.array([[-0.5] * 3, [0.5] * 3]))
    return path
