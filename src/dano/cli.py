"""The ``dano`` command line: ``dano <verb> ...``. Thin: parses, calls the library,
prints and saves. Every verb's options are its function's arguments (tyro)."""

from __future__ import annotations

import json
import sys
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated

import tyro
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

err = Console(stderr=True)
out = Console()


@contextmanager
def _progress(enabled: bool = True):
    """A rich progress bar as a ``progress(done, total, description)`` callback."""
    if not enabled:
        yield None
        return
    with Progress(TextColumn("{task.description}"), BarColumn(), TextColumn("{task.completed}/{task.total}"),
                  TimeElapsedColumn(), console=err, transient=True) as bar:
        tasks: dict[str, int] = {}

        def update(done: int, total: int, description: str) -> None:
            if description not in tasks:
                tasks[description] = bar.add_task(description, total=total)
            bar.update(tasks[description], completed=done, total=total)

        yield update


def build(
    source: Annotated[Path, tyro.conf.Positional],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))],
    mass: float | None = None,
    alpha: float | None = None,
    samples: int = 5000,
    band: tuple[float, float] | None = None,
    seed: int = 0,
    resolution: int = 96,
    edge_width: float | None = None,
    normals_mesh: Path | None = None,
    visual_mesh: Path | None = None,
    quiet: bool = False,
) -> None:
    """Build a DANO asset (.dano) from a density source.

    Args:
        source: a watertight mesh (.obj/.stl/.ply/.off, read as uniform density, units m), a voxel grid
            (.npz with arrays 'density' (nx, ny, nz) and 'bounds' (2, 3) [m]) or a paper collider (.jld2).
        out: the .dano file to write (written atomically).
        mass: total mass [kg]; sets the mass scale alpha. Not with --alpha.
        alpha: the mass scale alpha (mass = alpha * integral of density). Default 1.
        samples: number of boundary samples N.
        band: density band LO HI of the boundary samples; default [0.05, 0.95] x 99th-percentile density.
        seed: random seed (samples and quasi-Monte Carlo integration are deterministic given it).
        resolution: mesh sources: signed-distance grid nodes along the longest axis.
        edge_width: mesh sources: width of the smooth surface edge [m] (default a quarter grid cell).
        normals_mesh: .jld2 sources: level-set mesh to recompute degenerate (zero) normals from.
        visual_mesh: .jld2 sources: mesh (collider frame) stored for rendering.
        quiet: no progress bar.
    """
    from .asset import build as build_asset
    from .asset import save
    from .fields import VoxelField, mesh_field
    from .io import load_paper_collider, source_kind

    kind = source_kind(source)
    if not source.is_file():
        raise FileNotFoundError(f"{source}: no such file")
    with _progress(not quiet) as progress:
        if kind == "jld2":
            if band is not None or edge_width is not None:
                raise ValueError("--band and --edge-width do not apply to a .jld2 collider (its samples are fixed)")
            asset = load_paper_collider(source, normals_mesh=normals_mesh, visual_mesh=visual_mesh)
            if alpha is not None and mass is not None:
                raise ValueError("give either --mass or --alpha, not both")
            if mass is not None or alpha is not None:
                asset = asset.with_mass(mass if mass is not None else asset.mass * alpha / asset.alpha)
        else:
            if kind == "mesh":
                field = mesh_field(source, resolution=resolution, edge_width=edge_width,
                                   progress=(lambda d, t: progress(d, t, "signed distance")) if progress else None)
            else:
                field = VoxelField.load(source)
            asset = build_asset(field, alpha=alpha, mass=mass, num_samples=samples, band=band, seed=seed,
                                name=source.stem, source=str(source.name), progress=progress)
    save(asset, out)
    err.print(f"wrote {out} ({asset.num_samples} samples, mass {asset.mass:.6g})")


def _summary_table(asset) -> Table:
    s = asset.summary()
    t = Table(title=f"DANO asset: {asset.name}", show_header=False)
    fmt = lambda v: " ".join(f"{x: .5g}" for x in v)  # noqa: E731
    t.add_row("mass", f"{s['mass']:.6g}")
    t.add_row("mass scale α", f"{s['alpha']:.6g}")
    t.add_row("centre of mass (object frame)", fmt(s["center_of_mass"]))
    for i, row in enumerate(s["inertia"]):
        t.add_row("inertia about CoM" if i == 0 else "", fmt(row))
    t.add_row("principal moments", fmt(s["principal_moments"]))
    t.add_row("samples N", str(s["num_samples"]))
    t.add_row("density band", fmt(s["band"]))
    t.add_row("valid normals", f"{100 * s['normals_valid_fraction']:.1f} %")
    t.add_row("queryable field", "yes" if s["has_field"] else "no")
    t.add_row("visual mesh faces", str(s["mesh_faces"]))
    return t


def inspect(
    file: Annotated[Path, tyro.conf.Positional],
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    plot: Path | None = None,
) -> None:
    """Show a .dano asset: mass, centre of mass, inertia, principal moments, N, band, valid normals.

    Args:
        file: the .dano file.
        json_: print one JSON object (keys include mass, center_of_mass, inertia, num_samples, band,
            normals_valid_fraction) instead of a table.
        plot: also draw the samples, normals and centre of mass to this image (e.g. samples.png).
    """
    from .asset import load

    asset = load(file)
    if json_:
        print(json.dumps(asset.summary()))
    else:
        out.print(_summary_table(asset))
    if plot is not None:
        from .viz import plot_samples

        plot_samples(asset, plot)
        err.print(f"wrote {plot}")


def demo(out_dir: Path = Path("dano-demo")) -> None:
    """The main job on the embedded default: load the paper bunny shipped in the package,
    show its mass properties and draw its samples.

    Args:
        out_dir: folder for the outputs (summary JSON and plot).
    """
    from .data import load_builtin
    from .viz import plot_samples

    asset = load_builtin("bunny")
    out.print(_summary_table(asset))
    out_dir.mkdir(parents=True, exist_ok=True)
    from .asset import _atomic_write

    summary = json.dumps(asset.summary(), indent=2).encode()
    _atomic_write(out_dir / "bunny_summary.json", lambda f: f.write(summary))
    plot_samples(asset, out_dir / "bunny_samples.png")
    err.print(f"wrote {out_dir / 'bunny_summary.json'} and {out_dir / 'bunny_samples.png'}")


def bench(
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    suite: tuple[str, ...] = (),
    repeats: int = 3,
    out: Path | None = None,
) -> None:
    """Run the benchmarks (wall times; medians of repeats, first compiling call separate).

    Args:
        json_: print one JSON object.
        suite: suites to run (default all): build.
        repeats: timed repeats after the first call.
        out: also write the JSON here.
    """
    from .asset import _atomic_write
    from .bench import SUITES, run

    unknown = set(suite) - set(SUITES)
    if unknown:
        raise ValueError(f"unknown benchmark suite(s) {sorted(unknown)}; available: {', '.join(SUITES)}")
    result = run(list(suite) or None, repeats=repeats)
    text = json.dumps(result, indent=None if json_ else 2)
    if out is not None:
        _atomic_write(out, lambda f: f.write(text.encode()))
    print(text)


COMMANDS = {"build": build, "inspect": inspect, "demo": demo, "bench": bench}


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dano`` console script; returns the exit code."""
    from . import __version__
    from .errors import DanoError

    args = sys.argv[1:] if argv is None else argv
    if args and args[0] in ("--version", "-V"):
        print(f"dano {__version__}")
        return 0
    try:
        tyro.extras.subcommand_cli_from_dict(COMMANDS, args=args, prog="dano",
                                             description="Dynamics-augmented neural objects (DANOs).")
    except SystemExit as exc:  # tyro's own parse errors and --help
        return int(exc.code or 0)
    except (DanoError, ValueError, OSError) as exc:
        err.print(f"[bold red]error:[/] {exc}", highlight=False, markup=True, soft_wrap=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
