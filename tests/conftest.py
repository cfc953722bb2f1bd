import gc
import os
import resource
from pathlib import Path

# One XLA CPU thread, as the dano command line uses (must be set before JAX starts).
os.environ.setdefault("NPROC", "1")

import jax  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402

import dano  # noqa: E402,F401  (sets up JAX before any test imports it)

dano.enable_float64()  # physics and gradient tests compare in float64 (tests/test_float32.py: float32)
dano.enable_compilation_cache()

# The real data (meshes, the paper's colliders, the Menagerie, the real cube tosses):
# ../shared/data beside the repository, or $DANO_SHARED_DATA (as `dano bench` reads it).
SHARED = Path(os.environ.get("DANO_SHARED_DATA") or Path(__file__).resolve().parents[1] / ".." / "shared" / "data")
SHARED_MISSING = (f"{SHARED} not found (../shared/data beside the repository, or $DANO_SHARED_DATA): "
                  "real-data tests skipped")


def shared_path(*parts: str) -> Path:
    """A file under the real data folder; skips the calling test when the folder is missing."""
    if not SHARED.is_dir():
        pytest.skip(SHARED_MISSING)
    return SHARED.resolve().joinpath(*parts)


@pytest.fixture(scope="session")
def shared() -> Path:
    """The real data folder; tests that ask for it skip, with the reason, when it is missing."""
    return shared_path()


# ---------------------------------------------------------------- memory between test files

_MEMORY: dict[str, float] = {}  # test file -> growth of this process's peak resident set [MB]


def _peak_rss_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: kB


@pytest.fixture(scope="module", autouse=True)
def _free_compiled_functions(request):
    """After each test file, drop what JAX keeps in memory for it (compiled executables and
    traces of every jitted function, ~0.1-1 GB per file of MJX scenes; the persistent
    compilation cache on disk stays), so that an xdist worker does not accumulate every
    file's compilations. Its own module fixtures are finalised before this one."""
    before = _peak_rss_mb()
    yield
    jax.clear_caches()
    gc.collect()
    _MEMORY[request.node.nodeid] = _peak_rss_mb() - before


def pytest_sessionfinish(session):
    """With DANO_TEST_MEMORY set, each process reports its peak resident set (and the files
    that raised it most): on the terminal and in the pytest cache (dano/memory)."""
    if not os.environ.get("DANO_TEST_MEMORY"):
        return
    report = {"peak_rss_mb": round(_peak_rss_mb()),
              "largest_rises_mb": dict(sorted(((k, round(v)) for k, v in _MEMORY.items() if v >= 1),
                                              key=lambda kv: -kv[1])[:5])}
    workeroutput = getattr(session.config, "workeroutput", None)
    if workeroutput is not None:  # an xdist worker: its controller prints it
        workeroutput["dano_memory"] = report
    else:
        _REPORTS["main"] = report


_REPORTS: dict[str, dict] = {}


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    report = getattr(node, "workeroutput", {}).get("dano_memory")
    if report is not None:
        _REPORTS[node.gateway.id] = report


def pytest_terminal_summary(terminalreporter, config):
    if not _REPORTS:
        return
    terminalreporter.section("dano memory (DANO_TEST_MEMORY)")
    for who, report in sorted(_REPORTS.items()):
        rises = ", ".join(f"{Path(k).name} +{v}" for k, v in report["largest_rises_mb"].items())
        terminalreporter.write_line(f"{who}: peak RSS {report['peak_rss_mb']} MB (largest rises, MB: {rises})")
    if getattr(config, "cache", None) is not None:  # not with -p no:cacheprovider
        config.cache.set("dano/memory", _REPORTS)


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
