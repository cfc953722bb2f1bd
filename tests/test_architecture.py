"""The package's architecture (docs/architecture.md), checked on the repository's source tree.

Each check runs in a subprocess with ``PYTHONPATH=src``, so that it reads ``src/dano`` of this
checkout also where the package is installed non-editable (as on CI): the layers contract of
``pyproject.toml`` (import-linter), that the library never imports ``dano.experiments``
(grimp), and that ``import dano`` stays light (no MuJoCo, no MJX, no simulation stages).
"""

import json
import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SRC = REPO / "src"


def run_on_source(code: str) -> subprocess.CompletedProcess:
    """Run ``python -c code`` in the repository root with ``src`` first on the path."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(SRC)] + ([env["PYTHONPATH"]] if env.get("PYTHONPATH") else []))
    return subprocess.run([sys.executable, "-c", code], cwd=REPO, env=env, capture_output=True, text=True,
                          timeout=300)


def test_the_checks_read_the_source_tree():
    res = run_on_source("import dano; print(dano.__file__)")
    assert res.returncode == 0, res.stderr[-2000:]
    assert Path(res.stdout.strip()).resolve() == (SRC / "dano" / "__init__.py").resolve()


def test_layers_contract_is_kept():
    """``lint-imports`` with the contract of pyproject.toml: imports only go down the layers."""
    code = ("import sys\nfrom importlinter.cli import lint_imports\n"
            f"sys.exit(lint_imports(config_filename={str(REPO / 'pyproject.toml')!r}, no_cache=True))\n")
    res = run_on_source(code)
    assert res.returncode == 0, res.stdout[-4000:] + res.stderr[-2000:]
    assert "1 kept, 0 broken" in res.stdout, res.stdout[-4000:]


def test_the_library_never_imports_experiments():
    """Every module outside dano.experiments, dano.bench and dano.cli imports nothing from
    dano.experiments, directly or through other modules (function-level imports included)."""
    code = ("import grimp, json\n"
            "graph = grimp.build_graph('dano', cache_dir=None)\n"
            "users = graph.find_downstream_modules('dano.experiments', as_package=True)\n"
            "print(json.dumps({'modules': sorted(graph.modules), 'users': sorted(users)}))\n")
    res = run_on_source(code)
    assert res.returncode == 0, res.stderr[-2000:]
    graph = json.loads(res.stdout)
    assert "dano.experiments.sysid_examples" in graph["modules"] and "dano.sim.dynamics" in graph["modules"]
    users = set(graph["users"])
    assert "dano.cli" in users  # the graph is real: the command line runs experiments
    allowed = {"dano.bench", "dano.cli"}
    assert users <= allowed, f"library modules that import dano.experiments: {sorted(users - allowed)}"


def test_import_dano_stays_light():
    """``import dano`` loads fields, assets and importers only: no MuJoCo (nor MJX), no
    simulation, identification, optimisation, rendering or NeRF stage, no plotting, no
    experiments, none of the heavy readers (trimesh, scipy.stats, h5py: loaded where a mesh is
    read, an asset built, a .jld2 opened); and it starts no JAX backend."""
    code = (
        "import sys, json\n"
        "import dano\n"
        "from jax._src import xla_bridge\n"
        "backends = sorted(getattr(xla_bridge, '_backends', {}))\n"
        "print(json.dumps({'modules': sorted(sys.modules), 'backends': backends}))\n"
    )
    res = run_on_source(code)
    assert res.returncode == 0, res.stderr[-2000:]
    out = json.loads(res.stdout)
    loaded = set(out["modules"])
    assert {"dano.asset", "dano.fields", "dano.io", "dano.data"} <= loaded
    heavy = ["mujoco", "mujoco.mjx", "optax", "matplotlib", "dano._mjx", "dano.sim", "dano.contact", "dano.sysid",
             "dano.trajopt", "dano.render", "dano.nerf", "dano.tracking", "dano.viz", "dano.experiments",
             "dano.sources", "dano.bench", "dano.cli", "trimesh", "scipy.stats", "h5py", "dano.io.exporters"]
    assert not [m for m in heavy if m in loaded], [m for m in heavy if m in loaded]
    assert out["backends"] == [], out["backends"]
    # the simulation names are still there, loaded on first use
    res = run_on_source("import sys, dano\ndano.step\nassert {'mujoco.mjx', 'dano.sim'} <= set(sys.modules)\n")
    assert res.returncode == 0, res.stderr[-2000:]
