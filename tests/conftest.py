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


# the longest files (minutes of compilation and optimisation each), longest first
LONGEST_FILES = ("test_trajopt_panda.py", "test_trajopt.py", "test_sysid.py")


def pytest_collection_modifyitems(config, items):
    """The longest files first, then the other files with slow tests, then the rest (stable
    otherwise): pytest-xdist's --dist loadfile hands files to its workers in collection
    order, so the long files start at once on both workers instead of ending the run on
    one of them while the other idles."""
    slow_files = {item.path for item in items if item.get_closest_marker("slow")}

    def rank(item):
        name = item.path.name
        if name in LONGEST_FILES:
            return LONGEST_FILES.index(name)
        return len(LONGEST_FILES) + (item.path not in slow_files)

    items.sort(key=rank)
