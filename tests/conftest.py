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
import dano._compiled  # noqa: E402

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


def _malloc_trim() -> None:
    """Give the C heap's free pages back to the system (glibc; elsewhere nothing)."""
    try:
        import ctypes

        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _rss_mb() -> float:
    """This process's resident set now [MB] (Linux; elsewhere 0)."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20
    except (OSError, ValueError, IndexError):
        return 0.0


def _free_memory() -> None:
    """Drop what JAX keeps in memory: the compiled executables and traces of every jitted
    function (JAX keys them on the scene, and a scene compares by identity, so every test's
    new scenes add their own; 0.1-3 GB per file, and thousands of memory mappings: without
    this one process running the whole suite grew past 10 GB and crashed in a compilation
    at 81 %). The persistent compilation cache on disk stays: a later compilation of the
    same function loads it (tracing it again is what this costs)."""
    if os.environ.get("DANO_TEST_KEEP_CACHES"):  # to measure the difference (DANO_TEST_MEMORY=1)
        return
    jax.clear_caches()
    dano._compiled.clear()
    gc.collect()
    _malloc_trim()


# within a file, caches are dropped after a test that leaves more than this resident [MB]
RSS_LIMIT_MB = float(os.environ.get("DANO_TEST_RSS_LIMIT_MB", 2000))


@pytest.fixture(scope="module", autouse=True)
def _free_memory_after_each_file(request):
    """After each test file (its own module fixtures are finalised before this one)."""
    before = _peak_rss_mb()
    yield
    _free_memory()
    _MEMORY[request.node.nodeid] = _peak_rss_mb() - before


@pytest.fixture(autouse=True)
def _bound_memory_within_a_file():
    """After a test that leaves the process above RSS_LIMIT_MB (the files that build many
    scenes: test_sysid.py grew to 3.4 GB), so that a worker stays within about 3 GB."""
    yield
    if _rss_mb() > RSS_LIMIT_MB:
        _free_memory()


# ---------------------------------------------------------------- where a worker's time goes

# seconds of JAX's tracing, lowering and XLA compiling in this process (JAX's monitoring spans;
# nested spans each counted; a load from the persistent cache counts as a compile), XLA
# compiles split at 1 s (small programs: the many eager and helper ones; large: the MJX programs)
_SPANS: dict[str, float] = {}
_FILE_COMPILES: dict[str, list] = {}  # test file -> [XLA compiles over 1 s, their seconds]
_CURRENT_FILE = [""]


def _record_span(event: str, start: float, end: float, **_) -> None:
    duration = end - start
    if event.startswith("/jax/core/compile/"):
        name = event.rsplit("/", 1)[-1].removesuffix("_duration")
        if name == "backend_compile":
            name += "_over_1s" if duration >= 1.0 else "_under_1s"
            if duration >= 1.0:
                entry = _FILE_COMPILES.setdefault(_CURRENT_FILE[0], [0, 0.0])
                entry[0] += 1
                entry[1] += duration
        _SPANS[name] = _SPANS.get(name, 0.0) + duration


jax.monitoring.register_event_time_span_listener(_record_span)


@pytest.fixture(autouse=True)
def _note_the_test_file(request):
    _CURRENT_FILE[0] = request.node.path.name


def pytest_sessionfinish(session):
    """With DANO_TEST_MEMORY set, each process reports its peak resident set (and the files
    that raised it most) and its seconds of tracing, lowering and compiling: on the terminal
    and in the pytest cache (dano/memory)."""
    if not os.environ.get("DANO_TEST_MEMORY"):
        return
    report = {"peak_rss_mb": round(_peak_rss_mb()), "compile_s": {k: round(v) for k, v in sorted(_SPANS.items())},
              "largest_rises_mb": dict(sorted(((k, round(v)) for k, v in _MEMORY.items() if v >= 1),
                                              key=lambda kv: -kv[1])[:5]),
              "compiles_over_1s": dict(sorted(((k, [n, round(t)]) for k, (n, t) in _FILE_COMPILES.items()),
                                              key=lambda kv: -kv[1][1])[:12])}
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
        terminalreporter.write_line(f"{who}: peak RSS {report['peak_rss_mb']} MB (largest rises, MB: {rises}); "
                                    f"JAX seconds: {report['compile_s']}; XLA compiles over 1 s per file "
                                    f"[count, s]: {report['compiles_over_1s']}")
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


# seconds per file on one worker of the 2-core machine, cold compilation cache, measured at
# 02fd179 with this file's marks (fast tier: tests not marked slow; slow tier: marked slow);
# files under 5 s are left out
FILE_SECONDS = {"test_sysid.py": (100, 121), "test_grasp.py": (1, 155), "test_sharding.py": (0, 142),
                "test_contact_properties.py": (121, 0), "test_trajopt_panda.py": (1, 116),
                "test_step_api.py": (109, 0), "test_own_object_doc.py": (0, 109), "test_cli.py": (2, 75),
                "test_trajopt.py": (8, 68), "test_sim_gradients.py": (76, 0), "test_sysid_defaults.py": (1, 71),
                "test_contact_physics.py": (72, 0), "test_scenes.py": (71, 0), "test_nerf.py": (64, 0),
                "test_tracking.py": (34, 29), "test_sysid_uncertainty.py": (50, 12), "test_sim_physics.py": (56, 0),
                "test_sysid_real_cube.py": (2, 43), "test_inertial_params.py": (21, 20),
                "test_sim_bad_input.py": (40, 0), "test_sysid_rough.py": (0, 35), "test_float32.py": (33, 0),
                "test_compiled.py": (2, 28), "test_fuzz.py": (5, 20), "test_sysid_jagged.py": (24, 0),
                "test_golden_mujoco.py": (0, 22), "test_simulate_options.py": (22, 0), "test_pose.py": (20, 0),
                "test_export.py": (6, 13), "test_sources.py": (10, 0), "test_fields.py": (5, 0)}


def pytest_configure(config):
    # pytest-xdist (>= 3.6) hands out --dist loadfile's files sorted by their number of tests
    # (--loadscope-reorder, on by default), which would undo the order below: keep ours
    if hasattr(config.option, "loadscopereorder"):
        config.option.loadscopereorder = False


def _tier(config) -> slice:
    """Which of FILE_SECONDS' columns the run's marker expression selects."""
    expr = " ".join((getattr(config.option, "markexpr", "") or "").split())
    if expr == "not slow":
        return slice(0, 1)
    if expr == "slow":
        return slice(1, 2)
    return slice(0, 2)


def pytest_collection_modifyitems(config, items):
    """The files with the most seconds of the tests this run selects first (stable otherwise):
    pytest-xdist's --dist loadfile hands files to its workers in this order (see
    pytest_configure), so the long files start at once on both workers instead of ending the
    run on one of them while the other idles."""
    tier = _tier(config)
    items.sort(key=lambda item: -sum(FILE_SECONDS.get(item.path.name, (0, 0))[tier]))
