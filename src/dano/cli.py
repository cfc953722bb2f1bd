"""The ``dano`` command line: ``dano <verb> ...``. Thin: each verb is a typed configuration
(a frozen dataclass of the library whose field docstrings are its ``--help``), parsed by
tyro, one library call, and printing. Only the verb's own stage is imported."""

from __future__ import annotations

import dataclasses
import gc
import importlib
import inspect as _inspect
import json
import os
import signal
import sys
import time
import typing
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Annotated

import tyro
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn

from ._config import field_docs
from ._tables import asset_table, compare_table, simulation_table, sysid_table, trajopt_table
from ._files import json_safe
from .data import load_asset
from .errors import DanoError


def _console(stderr: bool = False) -> Console:
    """rich's console on standard output or error; where that is not a terminal (a pipe, a
    log) and COLUMNS does not say otherwise, 200 columns wide instead of rich's 80, so that
    tables keep every value and messages their lines."""
    console = Console(stderr=stderr)
    if console.is_terminal or os.environ.get("COLUMNS"):
        return console
    return Console(stderr=stderr, width=200)


err = _console(stderr=True)
out = _console()

#: verb -> (its configuration "module:Class", the runner below, the option naming its input file)
VERBS = {
    "build": ("dano.sources:BuildConfig", "_build", "source"),
    "simulate": ("dano.sim.run:SimulateCommandConfig", "_simulate", "scene"),
    "sysid": ("dano.experiments:SysIdCommandConfig", "_sysid", "config"),
    "export": ("dano.io.command:ExportConfig", "_export", "file"),
    "compare-mesh": ("dano.experiments.meshroute:CompareMeshConfig", "_compare_mesh", "source"),
    "trajopt": ("dano.experiments.trajopt_run:TrajoptCommandConfig", "_trajopt", "task"),
    "train-field": ("dano.nerf.train:TrainFieldConfig", "_train_field", "data"),
    "render-dataset": ("dano.nerf.synthetic:RenderDatasetConfig", "_render_dataset", "mesh"),
    "track": ("dano.tracking.outputs:TrackCommandConfig", "_track", "video"),
    "real2sim": ("dano.experiments.real2sim:Real2SimConfig", "_real2sim", None),
    "bench": ("dano.bench:BenchConfig", "_bench", None),
}


def config_class(verb: str) -> type:
    """The configuration dataclass of ``verb`` (its module imported now)."""
    module, name = VERBS[verb][0].split(":")
    return getattr(importlib.import_module(module), name)


def _verb(verb: str):
    """The function tyro parses for ``verb``: keyword arguments = the configuration's fields
    (their annotations, defaults and docstrings), body = build the configuration, run it.
    An error that does not name the verb's input file gets it as a prefix."""
    cls, runner, named = config_class(verb), globals()[VERBS[verb][1]], VERBS[verb][2]
    hints = typing.get_type_hints(cls, include_extras=True)
    docs = field_docs(cls)
    params = [_inspect.Parameter(f.name, _inspect.Parameter.KEYWORD_ONLY,
                                 annotation=_shown(hints[f.name], f.default, docs.get(f.name, ""), f.name),
                                 default=_inspect.Parameter.empty if f.default is dataclasses.MISSING else f.default)
              for f in dataclasses.fields(cls)]

    def run(**kwargs):
        label = str(kwargs.get(named)) if named else "None"
        try:
            return runner(cls(**kwargs))
        except (DanoError, ValueError) as exc:
            if label == "None" or label in str(exc):
                raise
            raise DanoError(f"{label}: {exc}") from exc

    run.__signature__ = _inspect.Signature(params)
    run.__annotations__ = {p.name: p.annotation for p in params}
    run.__name__ = run.__qualname__ = verb.replace("-", "_")
    run.__doc__ = (_inspect.getdoc(cls) or "").split("\n\n")[0] + "\n\nArgs:\n" + "\n".join(
        f"    {k}: {v}" for k, v in docs.items())
    return run


def _shown(annotation, default, doc: str, name: str = ""):
    """An option's annotation as its help shows it: an optional value left out by default
    reads FLOAT, not {None}|FLOAT (``None`` is not taken on the command line: leaving the
    option out gives it), and tyro's "(default: ...)" is left out where it would say None or
    nothing (an empty list) or where the option's own text already says what the default is;
    a flag named no_* is only --no-*, without tyro's --no-no-* twin."""
    extra = []
    if name.startswith("no_") and default is False:
        extra.append(tyro.conf.FlagCreatePairsOff)
    args = typing.get_args(typing.get_args(annotation)[0] if typing.get_origin(annotation) is Annotated else annotation)
    if default is None and type(None) in args:
        extra.append(tyro.conf.DisallowNone)
    if default is None or (isinstance(default, tuple) and not default) or "default" in doc.lower():
        extra.append(tyro.conf.arg(help_behavior_hint=""))
    return Annotated[(annotation, *extra)] if extra else annotation


def _error_line(exc: BaseException) -> str:
    """One line naming the file: OSError as '<file>: <reason>', whitespace runs folded."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


@contextmanager
def _progress(enabled: bool = True):
    """A rich progress bar as a ``progress(done, total, description)`` callback; None where
    not ``enabled`` or where standard error is not a terminal (a log file gets no bar, and no
    blank line where the bar was)."""
    if not (enabled and err.is_terminal):
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


def _train_progress(enabled: bool):
    """A rich progress bar over the run's clock (or steps) showing loss and training PSNR."""
    if not (enabled and err.is_terminal):  # (as _progress)
        return nullcontext()

    @contextmanager
    def bar():
        with Progress(TextColumn("training"), BarColumn(), TextColumn("{task.fields[info]}"), TimeElapsedColumn(),
                      console=err, transient=True) as p:
            task = p.add_task("training", total=1000, info="")

            def update(record):
                if record["step"] % 10 == 0 or record["step"] < 3:
                    p.update(task, completed=int(1000 * record["fraction"]),
                             info=f"step {record['step']}  loss {record['loss']:.4g}  "
                                  f"PSNR {record['psnr_train']:.2f} dB")

            yield update

    return bar()


def _primary() -> bool:
    """Whether this process prints and writes: the only one, or process 0 of a multi-process run."""
    import jax

    return jax.process_index() == 0


def _build(c) -> None:
    from .asset import density_warning
    from .sources import build_file

    with _progress(not c.quiet and not c.json_) as progress:
        result = build_file(c, progress=progress)
    cal, asset = result.calibration, result.asset
    summary = asset.summary()
    warning = density_warning(summary)  # (as dano inspect warns: a mesh in mm, a mass in g)
    if c.json_:
        _print_report({**summary, "file": str(c.out), "calibration": cal or None,
                       "warnings": [warning] if warning else []})
    if cal:
        err.print(f"solid surface moved out by {cal['surface_offset']:.4g} m ({cal['surface_offset_nodes']:.2f} nodes): "
                  f"silhouette area {cal['silhouette_area_ratio_before']:.3f} -> "
                  f"{cal['silhouette_area_ratio_after']:.3f} of the field's renders")
    err.print(f"wrote {c.out} ({asset.num_samples} samples, mass {asset.mass:.6g})")
    if warning:
        err.print(f"[yellow]warning:[/] {escape(f'{c.out}: {warning}')} (--scale 0.001 for a mesh in millimetres)",
                  highlight=False, soft_wrap=True)


def inspect(
    file: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="FILE.dano")],
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    plot: Annotated[Path | None, tyro.conf.DisallowNone, tyro.conf.arg(help_behavior_hint="")] = None,
) -> None:
    """Show a .dano asset: mass, centre of mass, inertia, principal moments, N, band, valid normals,
    extents, volume and mean density (a warning when the density is implausible, 10-25,000 kg/m³).

    Args:
        file: the .dano file (or builtin:NAME).
        json_: print one JSON object (keys include mass, center_of_mass, inertia, num_samples, band,
            normals_valid_fraction, extents, bounding_box, volume, mean_density) instead of a table.
        plot: also draw the samples, normals and centre of mass to this image (e.g. samples.png).
    """
    from .asset import density_warning

    if plot is not None:
        from .viz.plot import check_image_path

        check_image_path(plot, "--plot")
    try:
        asset = load_asset(file)
    except (DanoError, ValueError) as exc:
        raise exc if file in str(exc) else DanoError(f"{file}: {exc}") from exc
    summary = asset.summary()
    if json_:
        print(json.dumps(summary))
    else:
        out.print(asset_table(asset))
    warning = density_warning(summary)
    if warning:
        err.print(f"[yellow]warning:[/] {escape(f'{file}: {warning}')}", highlight=False, soft_wrap=True)
    if plot is not None:
        from .viz import plot_samples

        plot_samples(asset, plot)
        err.print(f"wrote {plot}")


def _simulate(c):
    from .sim.run import simulate, write_outputs

    with _progress(not c.quiet and not c.json_) as progress:
        run = simulate(c.resolved(), progress=progress)  # (a deep start is warned of by the rollout)
    if not c.json_:
        out.print(simulation_table(run.setup, run.trajectory, run.wall_time_s))
    with _progress(not c.quiet and not c.json_) as progress:
        written = write_outputs(run, out=c.out, video=c.video, progress=progress)
    for path in written:
        err.print(f"wrote {path}")
    if c.json_:
        _print_report({**run.summary(), "files": [str(p) for p in written]})
    return run


def _sysid(c) -> None:
    from .experiments import sysid_command

    if c.template:
        from .sysid.config import template

        print(template(c.template), end="")
        return
    problem, result, report, out_dir = sysid_command(c)
    if not _primary():
        return
    _print_sysid_warnings(c.config, report)
    if c.json_:
        _print_report(_sysid_json(report))
    else:
        out.print(sysid_table(c.config, problem, result, report, out_dir))
        _print_sysid_notes(report)


def _print_sysid_warnings(name, report: dict) -> None:
    for note in report["warnings"]:
        err.print(f"[yellow]warning:[/] {escape(f'{name}: {note}')}", highlight=False, soft_wrap=True)


def _print_sysid_notes(report: dict) -> None:
    """The result's notes (what the defaults decided: a drag held neutral, start velocities
    fitted, ...) after its table; --json carries them under "notes"."""
    for note in report.get("notes", []):
        out.print(f"[dim]note:[/] {escape(note)}", highlight=False, soft_wrap=True)


def _sysid_json(report: dict) -> dict:
    return {k: v for k, v in report.items() if k not in ("grid", "heldout_per_toss")}


def demo(out_dir: Annotated[Path, tyro.conf.arg(name="out", aliases=("-o", "--out-dir"))] = Path("dano-demo"),
         quiet: bool = False) -> None:
    """The main job on the embedded default: the paper's NeRF-derived bunny dropped on the
    ground (scene bunny-drop); writes the trajectory, a video, the asset's sample plot and a
    summary.

    Args:
        out_dir: folder for the outputs.
        quiet: no progress bars.
    """
    from .experiments.demo import demo as run_demo

    with _progress(not quiet) as progress:
        asset, run, _ = run_demo(out_dir, progress=progress)
    out.print(asset_table(asset))
    out.print(simulation_table(run.setup, run.trajectory, run.wall_time_s))
    for name in ("bunny-drop.npz", "bunny-drop.mp4", "bunny-drop.config.json", "bunny_samples.png", "summary.json"):
        err.print(f"wrote {out_dir / name}")


def _bench(c) -> None:
    from ._files import atomic_write
    from .bench import bench_command

    text = json.dumps(bench_command(c), indent=None if c.json_ else 2)
    if not _primary():
        return
    if c.out is not None:
        atomic_write(c.out, lambda f: f.write(text.encode()))
    print(text)


_STARTED = [time.time()]  # when main() began (wall_time_s of verbs that report no wall time of their own)


def _print_report(report: dict) -> None:
    """One JSON object; ``compile_time_s`` (seconds this process traced, lowered and compiled,
    :func:`dano._compiled.compile_seconds`) and ``wall_time_s`` added where the verb has none
    of its own, so that every compute verb's --json reports compile and run separately."""
    from ._compiled import compile_seconds

    report = dict(report)
    report.setdefault("compile_time_s", compile_seconds(_STARTED[0]))
    report.setdefault("wall_time_s", time.time() - _STARTED[0])
    print(json.dumps(report))


def _trajopt(c) -> None:
    from .experiments.trajopt_run import trajopt_command

    with _progress(not c.quiet and not c.json_) as progress:
        report, paths = trajopt_command(c, progress=progress)
    for warning in report.get("warnings", []):
        err.print(f"[yellow]warning:[/] {escape(warning)}", highlight=False, soft_wrap=True)
    if c.json_:
        _print_report(report)
        return
    out.print(trajopt_table(c.task, report, paths))


def _train_field(c) -> None:
    from .nerf.train import train_field

    with _train_progress(not c.quiet and not c.json_) as progress:
        report, result = train_field(c, progress=progress)
    if c.json_:
        _print_report(report)
        return
    err.print(f"held-out PSNR {report['psnr_heldout']:.2f} dB after {result.steps} steps, {result.wall_time_s:.0f} s "
              f"({result.rays_per_s:.0f} rays/s); wrote {c.out}/")


def _render_dataset(c) -> None:
    from .nerf.synthetic import render_dataset

    with _progress(not c.quiet) as progress:
        render_dataset(c.mesh, c.out, views=c.views, size=c.size, progress=progress)
    err.print(f"wrote {c.out}/transforms.json and {c.views} images of {c.size}x{c.size} px")


def _track(c) -> None:
    from .tracking.outputs import track_command

    with _progress(not c.quiet and not c.json_) as progress:
        report, files = track_command(c, progress=progress)
    if not c.json_:
        err.print(f"tracked {report['frames']} frames ({report['poor_frames']} poor, mean IoU "
                  f"{report['mean_iou']:.3f}, {report['time_per_frame_s']:.2f} s per frame); wrote "
                  f"{', '.join(files)} in {c.out}")
    if c.identify:  # the tracked poses -> friction (two stages), through dano sysid's own route
        from .experiments import SysIdCommandConfig, sysid_command
        from .tracking.outputs import poor_frames_warning, write_tracked_problem

        toml = write_tracked_problem(c.out, c.object, report["frame_interval_s"])
        try:
            problem, result, identified, sysid_dir = sysid_command(SysIdCommandConfig(config=str(toml),
                                                                                      out_dir=c.out / "sysid"))
        except DanoError as exc:  # the tracking's outputs stay; a script still gets its report
            if c.json_:
                _print_report({**report, "identification_error": str(exc)})
            raise
        identified["warnings"] = poor_frames_warning(report) + identified["warnings"]
        _print_sysid_warnings(toml, identified)
        report = {**report, "identification": _sysid_json(identified)}
        if not c.json_:
            out.print(sysid_table(str(toml), problem, result, identified, sysid_dir))
            _print_sysid_notes(identified)
    if c.json_:
        _print_report(report)


def _real2sim(c) -> None:
    from .experiments.real2sim import synthetic_slide_real2sim

    with _progress(not c.quiet and not c.json_) as progress:
        report = synthetic_slide_real2sim(c.out, c.friction, video_file=not c.no_video, progress=progress)
    if c.json_:
        _print_report(json_safe({k: v for k, v in report.items() if k != "per_frame"})[0])
    else:
        err.print(f"mu: true {report['mu_true']:.4f}, two-stage {report['mu_two_stage']:.4f}, pixels "
                  f"{report['mu_pixels']:.4f}; tracking RMS {report['track_rms_mm']:.1f} mm, "
                  f"{report['track_rms_deg']:.2f} deg; {report['wall_time_s']:.0f} s; wrote {c.out}")


def _export(c) -> None:
    from .io.command import export_command

    summary = export_command(c)
    if c.json_:
        print(json.dumps(summary))
    err.print(f"wrote {c.out} ({summary['collision_source'] if c.collision != 'none' else 'no collision geometry'})")


def _compare_mesh(c) -> None:
    from .experiments.meshroute import compare_mesh_command

    with _progress(not c.quiet) as progress:
        report, paths = compare_mesh_command(c, progress=progress)
    for path in paths:
        err.print(f"wrote {path}")
    if c.json_:
        _print_report(report)
    else:
        out.print(compare_table(report))


#: verbs that are plain functions (a few options each)
FUNCTIONS = {"inspect": inspect, "demo": demo}
ORDER = ("build", "inspect", "simulate", "sysid", "export", "compare-mesh", "trajopt", "train-field",
         "render-dataset", "track", "real2sim", "demo", "bench")


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


# options that take several values after one flag; tyro would keep only the last repetition
_MULTI_VALUE_FLAGS = ("--object", "--param", "--qvel", "--template", "--levels", "--collision", "--suite", "--eval-at", "--bounds", "--pose")


def _wide(args: list[str]) -> bool:
    """Verbs made of large array operations (training fields), which XLA's thread pool speeds
    up: on the 2-core machine one lego minute trained 30.8k rays/s (28.6 dB) with both cores,
    17.9k rays/s (25.8 dB) with NPROC=1, measured one after the other."""
    return bool(args) and (args[0] == "train-field" or (args[0] == "bench" and "nerf" in args
                                                                 and not {"sim", "batched", "energy"} & set(args)))


def _configure_process(args: list[str] | None = None) -> None:
    """The command line's own process: one XLA CPU thread unless NPROC is set (dano's
    steps are many small operations; on the 2-core machine XLA's thread pool made single
    and batched rollouts about 2x slower), JAX's 64-bit mode and the persistent compilation
    cache. A library user chooses these explicitly (see docs/simulation.md). Also: MuJoCo's
    warnings go to stderr (not to MUJOCO_LOG.TXT in the working folder) and SIGTERM unwinds
    like an exception, so that temporary files are removed and no partial output is left."""
    import os

    from . import _jax_setup

    if os.environ.get("DANO_NUM_PROCESSES", "").strip():  # a multi-process run (docs/scaling.md) joins first
        from . import sharding

        sharding.initialize_from_environment()
    if "NPROC" not in os.environ and not _jax_setup._backend_started() and not _wide(args):
        os.environ["NPROC"] = "1"
    _jax_setup.enable_float64()
    _jax_setup.enable_compilation_cache()
    import mujoco

    # MuJoCo's own warnings become dano's messages instead of MUJOCO_LOG.TXT in the working folder
    mujoco.set_mju_user_warning(lambda msg: err.print(f"[yellow]warning:[/] MuJoCo: {escape(msg)}", highlight=False,
                                                      soft_wrap=True))
    # SIGTERM unwinds like Ctrl-C: temporary files are removed, no partial output is left
    signal.signal(signal.SIGTERM, _terminate)
    # Python warnings (numpy, JAX, MJX): one line each, like dano's own messages
    import warnings

    from .errors import DanoWarning

    # library deprecations speak to developers, not to the user of a command (Python's own
    # default outside __main__); a test run turns them on, and NumPy 2.5's deprecation in
    # scikit-image's marching cubes then printed as a warning of `dano build`
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    warnings.filterwarnings("ignore", category=PendingDeprecationWarning)
    warnings.showwarning = lambda message, category, *rest: err.print(
        "[yellow]warning:[/] " + ("" if issubclass(category, DanoWarning) else f"{category.__name__}: ")
        + escape(" ".join(str(message).split())), highlight=False, soft_wrap=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dano`` console script; returns the exit code."""
    from . import __version__
    from .errors import DanoError

    _STARTED[0] = time.time()
    args = list(sys.argv[1:] if argv is None else argv)
    debug = "--debug" in args
    args = [a for a in args if a != "--debug"]
    if args and args[0] in ("--version", "-V"):
        print(f"dano {__version__}")
        return 0
    _configure_process(args)
    for flag in _MULTI_VALUE_FLAGS:
        if sum(a == flag or a.startswith(flag + "=") for a in args) > 1:
            err.print(f"[bold red]error:[/] {flag} is given more than once; give all its values after one {flag} "
                      f"(e.g. {flag} A B)", highlight=False, soft_wrap=True)
            return 2
    try:
        verb = args[0] if args else None
        if verb in VERBS or verb in FUNCTIONS:  # only this verb's stage is imported
            tyro.cli(_verb(verb) if verb in VERBS else FUNCTIONS[verb], args=args[1:], prog=f"dano {verb}")
        else:  # no verb, --help or a typo: every verb's help
            commands = {v: _verb(v) if v in VERBS else FUNCTIONS[v] for v in ORDER}
            tyro.extras.subcommand_cli_from_dict(commands, args=args, prog="dano",
                                                 description="Dynamics-augmented neural objects (DANOs).")
    except SystemExit as exc:  # tyro's own parse errors and --help
        return int(exc.code or 0)
    except KeyboardInterrupt:
        err.print("[bold red]interrupted[/]", highlight=False)
        return 130
    except Exception as exc:
        if debug:
            raise
        known = isinstance(exc, (DanoError, ValueError, OSError))
        text = _error_line(exc) if known else (f"internal error ({type(exc).__name__}: {_error_line(exc)}); "
                                               "please report it, with the output of --debug")
        err.print(f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True)
        return 1
    return 0


def console_main() -> None:
    """The ``dano`` console script: :func:`main`, then exit with its code. The objects left
    are frozen out of the garbage collector first (:func:`gc.freeze`), so that the
    interpreter's last collection at exit skips them: it took 0.3–0.4 s after a warm
    ``dano sysid soap`` had finished (2-core VM, measured). Objects in reference cycles are
    then not finalised at exit, which Python does not promise anyway; the outputs are
    written and closed by then, and the ``atexit`` handlers (temporary files, logging) still
    run."""
    code = main()
    gc.freeze()
    sys.exit(code)


if __name__ == "__main__":
    console_main()
