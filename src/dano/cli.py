"""The ``dano`` command line: ``dano <verb> ...``. Thin: parses, calls the library,
prints and saves. Every verb's options are its function's arguments (tyro)."""

from __future__ import annotations

import dataclasses
import json
import math
import signal
import sys
from contextlib import contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import tyro
from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from ._files import atomic_write
from .data import load_asset
from .sources import check_resolution as _check_resolution

err = Console(stderr=True)
out = Console()


def _names(param: str):
    """Decorator of a verb: an error whose message does not name the verb's file or scene
    (argument ``param``) gets it as a prefix, ``<file>: <problem>``."""
    import functools
    import inspect as _inspect

    def decorate(fn):
        @functools.wraps(fn)
        def verb(*args, **kwargs):
            from .errors import DanoError

            name = str(_inspect.signature(fn).bind(*args, **kwargs).arguments.get(param))
            try:
                return fn(*args, **kwargs)
            except (DanoError, ValueError) as exc:
                if name == "None" or name in str(exc):
                    raise
                raise DanoError(f"{name}: {exc}") from exc

        return verb

    return decorate


def _json_safe(obj, where: str = ""):
    """(copy of ``obj`` with non-finite floats as None, the keys where that happened):
    NaN is not JSON, and a NaN standard error must not pass silently."""
    found: list[str] = []

    def clean(x, key):
        if isinstance(x, float) and not math.isfinite(x):
            found.append(key)
            return None
        if isinstance(x, dict):
            return {k: clean(v, f"{key}.{k}" if key else str(k)) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [clean(v, f"{key}[{i}]") for i, v in enumerate(x)]
        return x

    return clean(obj, where), found


def _error_line(exc: BaseException) -> str:
    """One line naming the file: OSError as '<file>: <reason>', whitespace runs folded."""
    if isinstance(exc, OSError) and exc.filename and exc.strerror:
        text = f"{exc.filename}: {exc.strerror}"
    else:
        text = str(exc) or type(exc).__name__
    return " ".join(text.split())


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


@_names("source")
def build(
    source: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")],
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
    density_rule: str = "solid",
    surface_opacity: float = 0.5,
    calibrate_surface: bool = True,
    field_scale: float = 1.0,
    voxels: Path | None = None,
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
        density_rule: field folders: how sigma becomes density: solid (the seen surface filled, uniform inside),
            occupancy (1 - exp(-sigma*step)) or sigma (the paper's); see docs/fields-from-images.md.
        surface_opacity: field folders, solid rule: the surface is where the opacity accumulated from outside
            reaches this (0.5: a render's median depth).
        calibrate_surface: field folders, solid rule: then move that surface along its normal so that the
            solid's silhouettes cover as many pixels as the field's own renders from 12 views around it
            (a soft field's median-depth surface lies inside the object).
        field_scale: field folders: metres per field unit (1 for fields trained on `dano render-dataset` views).
        voxels: field folders: also write the density grid as a voxel .npz (density, bounds), loadable anywhere.
        quiet: no progress bar.
    """
    from .asset import save
    from .sources import build_from_source

    with _progress(not quiet) as progress:
        result = build_from_source(source, mass=mass, alpha=alpha, samples=samples, band=band, seed=seed,
                                   resolution=resolution, edge_width=edge_width, normals_mesh=normals_mesh,
                                   visual_mesh=visual_mesh, density_rule=density_rule, surface_opacity=surface_opacity,
                                   calibrate_surface=calibrate_surface, field_scale=field_scale, voxels=voxels,
                                   progress=progress)
    c, asset = result.calibration, result.asset
    if c:
        err.print(f"solid surface moved out by {c['surface_offset']:.4g} m ({c['surface_offset_nodes']:.2f} nodes): "
                  f"silhouette area {c['silhouette_area_ratio_before']:.3f} -> {c['silhouette_area_ratio_after']:.3f} "
                  "of the field's renders")
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
    t.add_row("extents (bounding box)", fmt(s["extents"]) + " m")
    if s["volume"] is not None:
        t.add_row("volume", f"{s['volume']:.4g} m³ ({s['volume_source']})")
        t.add_row("mean density", f"{s['mean_density']:.4g} kg/m³")
    return t


#: mean densities [kg/m³] outside this range are not plausible for a solid object in metres and kilograms
PLAUSIBLE_DENSITY = (10.0, 25_000.0)


def _density_warning(s: dict) -> str | None:
    rho = s["mean_density"]
    if rho is None or PLAUSIBLE_DENSITY[0] <= rho <= PLAUSIBLE_DENSITY[1]:
        return None
    return (f"mean density {rho:.3g} kg/m³ (mass {s['mass']:.3g} kg, extents "
            + " x ".join(f"{e:.3g}" for e in s["extents"]) + " m) is outside "
            f"{PLAUSIBLE_DENSITY[0]:g}-{PLAUSIBLE_DENSITY[1]:g} kg/m³: is the object in metres and its mass in kg?")


@_names("file")
def inspect(
    file: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="FILE.dano")],
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    plot: Path | None = None,
) -> None:
    """Show a .dano asset: mass, centre of mass, inertia, principal moments, N, band, valid normals,
    extents, volume and mean density (a warning when the density is implausible, 10-25,000 kg/m³).

    Args:
        file: the .dano file (or builtin:NAME).
        json_: print one JSON object (keys include mass, center_of_mass, inertia, num_samples, band,
            normals_valid_fraction, extents, bounding_box, volume, mean_density) instead of a table.
        plot: also draw the samples, normals and centre of mass to this image (e.g. samples.png).
    """
    asset = load_asset(file)
    summary = asset.summary()
    if json_:
        print(json.dumps(summary))
    else:
        out.print(_summary_table(asset))
    warning = _density_warning(summary)
    if warning:
        err.print(f"[yellow]warning:[/] {file}: {warning}", highlight=False, soft_wrap=True, markup=True)
    if plot is not None:
        from .viz import plot_samples

        plot_samples(asset, plot)
        err.print(f"wrote {plot}")


def _simulate_summary(setup, traj, wall: float) -> Table:
    import numpy as np

    scene = setup.scene
    t = Table(title=f"{scene.name}: {len(traj.time) - 1} steps of {scene.dt:g} s ({traj.time[-1]:.3g} s)")
    t.add_column("")
    for name in scene.dano_names:
        t.add_column(name)
    p_end = [traj.dano_pose(n)[0][-1] for n in scene.dano_names]
    v_end = [traj.qvel[-1, a : a + 3] for a in scene.dof_adr]
    t.add_row("final centre of mass", *[" ".join(f"{x:.3f}" for x in p) for p in p_end])
    t.add_row("final speed [m/s]", *[f"{np.linalg.norm(v):.2e}" for v in v_end])
    t.add_row("mass", *[f"{a.mass:.4g}" for a in scene.assets])
    t.caption = (f"pairs: {', '.join(scene.pair_names)}; final overlap ψ: "
                 + ", ".join(f"{x:.3g}" for x in traj.psi[-1])
                 + f"; wall time {wall:.2f} s (compilation included)")
    return t


@_names("scene")
def simulate(
    scene: Annotated[str | None, tyro.conf.Positional, tyro.conf.arg(metavar="SCENE")] = None,
    config: Path | None = None,
    duration: float | None = None,
    dt: float | None = None,
    param: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VALUE")] = (),
    object: Annotated[tuple[str, ...], tyro.conf.arg(metavar="FILE@X,Y,Z")] = (),
    out: Path | None = None,
    video: Path | None = None,
    fps: float | None = None,
    contact_model: str | None = None,
    max_steps: int | None = None,
    quiet: bool = False,
):
    """Simulate a built-in scene or an MJCF file with DANOs and write the trajectory and a video.

    Args:
        scene: built-in name (bunny-drop, bunny-slide, sphere-hits-bunny, two-bunnies-sphere,
            panda-push-bunny) or an MJCF path (optional with --config).
        config: a configuration (TOML or JSON, e.g. the <out>.config.json a run saved) whose values are used
            for every option not given on the command line; the run then repeats that one.
        duration: simulated time [s] (default: the scene's).
        dt: time step [s] (default: the scene's; for an MJCF, its <option timestep>, else 0.01).
        param: contact parameters name=value for all pairs, or PAIR:name=value for one pair
            (e.g. sliding_friction=0.3, bunny/ground:impact_spring=5e4, alpha=0.2).
        object: MJCF scenes: DANOs to add, FILE.dano or builtin:NAME, optionally @x,y,z or
            @x,y,z,qw,qx,qy,qz (position [m] and orientation, world frame)
            (default: builtin:bunny@0,0,1).
        out: trajectory .npz (time, qpos, qvel, psi, names).
        video: .mp4 (or .gif) video, rendered headless with MuJoCo.
        fps: video frame rate (default 30).
        contact_model: DANO contact model of every pair: centroid (the paper's, default) or per_sample.
        max_steps: refuse a run of more steps than this (duration / dt) up front (default 2000000).
        quiet: no progress bars.
    """
    from .sim.run import SimulateConfig, check_video_path, simulate, write_outputs

    given = {"duration": duration, "dt": dt, "param": param, "object": object, "fps": fps,
             "contact_model": contact_model, "max_steps": max_steps}
    given = {k: v for k, v in given.items() if v not in (None, ())}
    if config is not None:
        saved = SimulateConfig.read(config)
        cfg = dataclasses.replace(saved, scene=scene or saved.scene, **given)
    elif scene is None:
        raise ValueError("give a SCENE (or --config)")
    else:
        cfg = SimulateConfig(scene, **given)
    check_video_path(video)
    with _progress(not quiet) as progress:
        run = simulate(cfg, progress=progress)
    Console().print(_simulate_summary(run.setup, run.trajectory, run.wall_time_s))  # `out` is the option here
    with _progress(not quiet) as progress:
        written = write_outputs(run, out=out, video=video, progress=progress)
    for path in written:
        err.print(f"wrote {path}")
    return run


@_names("config")
def sysid(
    config: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="CONFIG")],
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    out_dir: Path | None = None,
    jacobian: str | None = None,
    no_noise: bool = False,
    data: Path | None = None,
    tosses: int = 10,
    start: float = 0.3,
    contact_model: str = "centroid",
    bootstrap: int = 0,
) -> None:
    """Identify friction and mass scale from observed trajectories (Gauss-Newton/LM with AD Jacobians).

    Args:
        config: a TOML problem file, or a built-in example: soap (the paper's real soap video),
            bunny-pushes (the paper's bunny pushed 10 times by a sphere), bunny-dynamics (the same pushes with
            the bunny's centre of mass and inertia unknown as well), contactnets-cube (real cube tosses:
            friction, impact spring and damper and the table height on half the tosses, the other half
            predicted; needs --data).
        json_: print one JSON object (estimates as top-level keys, e.g. sliding_friction, with
            <name>_std, wall_time_s, compile_time_s, cost_history, ...).
        out_dir: write result.json, config.json (the resolved configuration) and fit.png here
            (default: sysid-<name>/).
        jacobian: ad (forward-mode AD, default) or fd (finite differences, for comparison).
        no_noise: bunny-pushes, bunny-dynamics: observations without the 1 mm / 0.5 deg pose noise.
        data: contactnets-cube: the ContactNets tosses (.npz of toss_<n> arrays, (T, 13) each; not shipped with
            dano, e.g. shared/data/real/contactnets_cube/tosses_100_299.npz).
        tosses: contactnets-cube: use the first this many tosses (even ones fitted, odd ones held out).
        start: contactnets-cube: initial guess of the sliding friction.
        contact_model: contactnets-cube: centroid (the paper's) or per_sample.
        bootstrap: contactnets-cube: also refit this many resamples of the fitted tosses (with replacement) for a
            95 % interval, key "bootstrap" of the JSON (TOML problems: [options] bootstrap).
    """
    from .experiments import is_experiment, run_sysid
    from .sysid.config import run
    from .sysid.outputs import write_outputs

    if config.lower().endswith(".json") and Path(config).is_file():
        from ._config import read_table

        saved = read_table(config)
        if saved.get("example") == "contactnets-cube":  # rerun what a contactnets-cube run saved
            config, data = "contactnets-cube", data or Path(str(saved.get("data", "")))
            tosses, start = int(saved.get("tosses", tosses)), float(saved.get("start", start))
            contact_model = str(saved.get("contact_model", contact_model))
            bootstrap = int(saved.get("bootstrap", bootstrap))
        elif "example" in saved:  # the config.json of a built-in example reruns it
            if not is_experiment("sysid", saved["example"]):
                from .errors import FileFormatError
                from .experiments import names

                raise FileFormatError(f"{config}: unknown example {saved['example']!r}; one of "
                                      f"{', '.join(names('sysid'))}")
            noise_saved = saved.get("noise", {})
            no_noise = no_noise or (isinstance(noise_saved, dict) and noise_saved.get("position_m") == 0)
            config = saved["example"]
    if config == "contactnets-cube":
        if data is None:
            raise ValueError("contactnets-cube needs --data: the ContactNets tosses .npz (arrays toss_<n>, not "
                             "shipped with dano)")
        problem, result, run_out = run_sysid(config, data=data, tosses=tosses, start=start,
                                             contact_model=contact_model, bootstrap=bootstrap)
    elif is_experiment("sysid", config):
        problem, result, run_out = run_sysid(config, jacobian=jacobian, noise=not no_noise)
    else:
        if Path(config).suffix.lower() not in (".toml", ".json") and not Path(config).exists():
            from .experiments import names

            raise ValueError(f"unknown identification {config!r}: give a TOML file, a saved config.json or one of "
                             f"{', '.join(names('sysid'))}")
        problem, result, run_out = run(config, jacobian=jacobian)
    report, nonfinite = _json_safe(run_out["report"])
    notes = list(report.get("warnings", result.warnings))
    if nonfinite:
        notes.append(f"not finite (written as null): {', '.join(nonfinite)}; the data do not determine these (check "
                     "that positions are in metres and that the motion excites the parameters)")
    report["warnings"] = notes
    for note in notes:
        err.print(f"[yellow]warning:[/] {config}: {note}", highlight=False, soft_wrap=True)
    out_dir = out_dir or Path(f"sysid-{Path(config).stem}")
    write_outputs(out_dir, report, run_out["config"], problem, result)
    if json_:
        print(json.dumps({k: v for k, v in report.items() if k not in ("grid", "heldout_per_toss")}))
        return
    out.print(_sysid_table(config, problem, result, report, out_dir))


def _sysid_table(config: str, problem, result, report: dict, out_dir: Path) -> Table:
    t = Table(title=f"identification: {config}")
    if config == "contactnets-cube":
        t.add_column("quantity")
        t.add_column("value")
        for key in ("sliding_friction", "impact_spring", "impact_damper", "ground_height"):
            sd = report[key + "_std"]
            t.add_row(key.replace("_", " "), f"{report[key]:.5g}" + ("" if sd is None else f" ± {sd:.2g}"))
        for key in ("heldout_position_rms_mm", "heldout_rotation_rms_deg", "grid_best_friction",
                    "grid_heldout_position_rms_mm", "grid_heldout_rotation_rms_deg"):
            t.add_row(key.replace("_", " "), f"{report[key]:.4g}")
        t.caption = f"{report['wall_time_s']:.1f} s (+{report['compile_time_s']:.1f} s compile); wrote {out_dir}/"
        return t
    for c in ("parameter", "estimate", "std. error", "initial"):
        t.add_column(c)
    for lab, v, sd, x0 in zip(result.labels, result.estimates, result.standard_errors, result.initial):
        t.add_row(lab, f"{v:.5g}", f"{sd:.2g}", f"{x0:.4g}")
    t.caption = (f"rms residual {result.rms_residual:.3g} over {result.num_residuals} residuals; "
                 f"{result.nfev} evaluations; {result.wall_time_s:.2f} s (+{result.compile_time_s:.1f} s compile); "
                 f"wrote {out_dir}/result.json, config.json, fit.png")
    return t


def demo(out_dir: Path = Path("dano-demo"), quiet: bool = False) -> None:
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
    out.print(_summary_table(asset))
    Console().print(_simulate_summary(run.setup, run.trajectory, run.wall_time_s))
    for name in ("bunny-drop.npz", "bunny-drop.mp4", "bunny-drop.config.json", "bunny_samples.png", "summary.json"):
        err.print(f"wrote {out_dir / name}")


def bench(
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    suite: tuple[str, ...] = (),
    repeats: int = 3,
    drops: int = 1000,
    seed: int = 0,
    contact_model: str = "centroid",
    nerf_minutes: float = 3.0,
    nerf_loop_minutes: float = 3.0,
    tracking_colour_minutes: float = 0.0,
    cube_data: Path | None = None,
    cube_tosses: int = 10,
    out: Path | None = None,
) -> None:
    """Run the benchmarks (wall times; medians of repeats, first compiling call separate).

    Args:
        json_: print one JSON object.
        suite: suites to run (default all): build, sim, sysid, batched, trajopt, energy, nerf (fields from
            images; needs the shared data, see benchmarks/README.md).
        repeats: timed repeats after the first call.
        drops: random bunny drops of the energy suite.
        seed: random seed of the energy suite's drops.
        contact_model: contact model of the energy suite (centroid or per_sample).
        nerf_minutes: training time of the nerf suite's lego run (PSNR also at 1 minute).
        nerf_loop_minutes: training time per mesh of the nerf suite's ground-truth loop (0: skip it).
        tracking_colour_minutes: tracking suite: also train a radiance field of the slide's bunny this long and
            track 15 frames photometrically with colour weights 0, 0.02, 0.1 and 1 (0: skip it).
        cube_data: sysid suite: also time the contactnets-cube identification on this ContactNets .npz
            (not shipped with dano).
        cube_tosses: sysid suite: tosses of that run.
        out: also write the JSON here.
    """
    from .bench import SUITES, run

    unknown = set(suite) - set(SUITES)
    if unknown:
        raise ValueError(f"unknown benchmark suite(s) {sorted(unknown)}; available: {', '.join(SUITES)}")
    if not 1 <= drops <= 1_000_000:
        raise ValueError(f"--drops must be 1 to 1000000, got {drops}")
    if not 1 <= repeats <= 1000:
        raise ValueError(f"--repeats must be 1 to 1000, got {repeats}")
    _check_contact_model(contact_model)
    if cube_data is not None and not cube_data.is_file():
        raise ValueError(f"--cube-data {cube_data}: no such file")
    if not 2 <= cube_tosses <= 200:
        raise ValueError(f"--cube-tosses must be 2 to 200, got {cube_tosses}")
    result = run(list(suite) or None, repeats=repeats,
                 options={"energy": {"drops": drops, "seed": seed, "contact_model": contact_model},
                          "sysid": {"cube_data": None if cube_data is None else str(cube_data),
                                    "cube_tosses": cube_tosses},
                          "nerf": {"minutes": nerf_minutes, "loop_minutes": nerf_loop_minutes,
                                   "eval_at": tuple(m for m in (1.0, 3.0) if m < nerf_minutes)},
                          "tracking": {"colour_minutes": tracking_colour_minutes}})
    text = json.dumps(result, indent=None if json_ else 2)
    if out is not None:
        atomic_write(out, lambda f: f.write(text.encode()))
    print(text)


@_names("task")
def trajopt(
    task: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="TASK|CONFIG")],
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    out_dir: Path | None = None,
    model_error: float | None = None,
    max_iterations: int | None = None,
    contact_model: str | None = None,
    no_video: bool = False,
    quiet: bool = False,
) -> None:
    """Optimise a robot motion through contact (constrained iLQR with an augmented Lagrangian).

    Args:
        task: a built-in task (push-sphere: the paper's sphere pushing the bunny 1.0 sideways of a plain push;
            push-panda: the Menagerie Panda's joint torques pushing a 15 cm bunny 10 cm, needs MENAGERIE_ROOT;
            grasp-panda: the Panda's hand grasps, lifts and holds the 15 cm bunny, needs MENAGERIE_ROOT)
            or a TOML/JSON configuration (key task and the task's settings, e.g. the config.json a run saved).
        json_: print one JSON object (bunny_final_error, pusher_final_error, max_constraint_violation,
            iterations, converged, status, wall_time_s, compile_time_s, ...; model_error with --model-error;
            grasp-panda: lift_height, slip_mm, slip_deg, grip_force, converged, wall_time_s, contact_models, ...).
        out_dir: write report.json, config.json, solution.npz, log.csv, convergence.png and the video here
            (default: trajopt-<task>/).
        model_error: also run the plan in a world with (1 + this) times the sliding friction: open loop and
            with receding horizon (e.g. 0.3).
        max_iterations: iLQR iterations in all (default 300).
        contact_model: DANO contact model: centroid (the paper's, default) or per_sample.
        no_video: skip the video.
        quiet: no progress bars.
    """
    from .experiments.trajopt_run import run, write_outputs

    if contact_model is not None:
        _check_contact_model(contact_model)
    with _progress(not quiet and not json_) as progress:
        problem, solution, me, report = run(task, progress=progress, model_error=model_error,
                                            max_iterations=max_iterations, contact_model=contact_model)
    report, nonfinite = _json_safe(report)
    if nonfinite:
        report["warnings"] = [f"not finite (written as null): {', '.join(nonfinite)}"]
    out_dir = out_dir or Path(f"trajopt-{problem.config.task}")
    with _progress(not quiet and not json_) as progress:
        paths = write_outputs(problem, solution, me, report, out_dir, video=not no_video, progress=progress)
    if json_:
        print(json.dumps(report))
        return
    t = Table(title=f"trajectory optimisation: {task}")
    t.add_column("quantity")
    t.add_column("value")
    keys = ("status", "iterations", "bunny_final_error", "pusher_final_error", "max_constraint_violation", "cost")
    if report["task"] == "grasp-panda":
        keys = ("status", "grip_force", "lift_height", "slip_mm", "slip_deg", "wall_time_s")
    for key in keys:
        v = report[key]
        t.add_row(key.replace("_", " "), f"{v:.4g}" if isinstance(v, float) else str(v))
    for key in ("max_control_ratio", "joint_limit_violation"):
        if key in report:
            t.add_row(key.replace("_", " "), f"{report[key]:.4g}")
    for key, v in (report.get("model_error") or {}).items():
        if isinstance(v, float):
            t.add_row(key.replace("_", " "), f"{v:.4g}")
    for model, r in (report.get("contact_models") or {}).items():
        t.add_row(f"{model}: lift, slip", f"{r['lift_height']:.4g} m, {r['slip_mm']:.4g} mm, {r['slip_deg']:.3g} deg")
    t.caption = (f"{report['wall_time_s']:.1f} s (of which {report['compile_time_s']:.1f} s compiling); "
                 f"wrote {', '.join(str(p) for p in paths)}")
    out.print(t)


def _train_progress(enabled: bool):
    """A rich progress bar over the run's clock (or steps) showing loss and training PSNR."""
    if not enabled:
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


@_names("data")
def train_field(
    data: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="DATA")],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))],
    minutes: float = 3.0,
    steps: int = 0,
    holdout: int = 10,
    bounds: tuple[float, float, float, float, float, float] | None = None,
    background: str = "white",
    mask_weight: float = 0.0,
    rays_per_step: int = 4096,  # TrainConfig's default (a test checks they agree)
    eval_at: tuple[float, ...] = (),
    seed: int = 0,
    resume: bool = False,
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    quiet: bool = False,
) -> None:
    """Train a density (radiance) field from posed images; `dano build DIR` makes it a DANO.

    Args:
        data: a transforms.json (Blender/nerfstudio; or its folder) or an .npz image set (images, poses, focal).
        out: the field directory to write (field.json, field.npz, optimizer.npz, config.json, report.json,
            log.csv, heldout.png). Checkpoints are written every 2 minutes of training; an interrupted run
            keeps its last checkpoint (continue it with --resume).
        minutes: training time (compilation included, evaluation excluded).
        steps: also stop after this many steps (0: only the clock stops).
        holdout: views held out for the PSNR (evenly spread over the set).
        bounds: the object box XLO YLO ZLO XHI YHI ZHI [data units] (default: the data's, else +-1.5).
        background: white, black or random (random needs RGBA images).
        mask_weight: weight of an alpha (mask) loss; needs RGBA images.
        rays_per_step: rays per Adam step.
        eval_at: also measure held-out PSNR when training passes these minutes (e.g. 1 3).
        seed: random seed.
        resume: continue the run checkpointed in OUT.
        json_: print one JSON object (psnr_heldout, wall_time_s, rays_per_s, steps, psnr_at_minutes, ...).
        quiet: no progress bar.
    """
    import numpy as np

    from .nerf import TrainConfig, load_dataset, train
    from .nerf.train import write_outputs

    if out.exists() and not resume and (not out.is_dir() or any(out.iterdir())):
        hint = " (a field directory: --resume continues it)" if (out / "field.json").exists() else ""
        raise ValueError(f"{out}: exists and is not empty{hint}; choose a new output folder")
    if resume and not (out / "field.json").exists():
        raise ValueError(f"{out}: --resume needs a field directory written by `dano train-field`")
    box = None if bounds is None else np.asarray(bounds, dtype=np.float64).reshape(2, 3)
    dataset = load_dataset(data, bounds=box)
    config = TrainConfig(minutes=minutes, steps=steps, holdout=holdout, background=background,
                         mask_weight=mask_weight, rays_per_step=rays_per_step, eval_at_minutes=tuple(eval_at),
                         seed=seed).check_data(dataset)
    train_set, held = dataset.split(holdout)
    with _train_progress(not quiet and not json_) as progress:
        result = train(train_set, config, heldout=held, out_dir=out, resume=resume, progress=progress)
    report = write_outputs(out, result, config, dataset, train_set, held, data)
    score = report["psnr_heldout"]
    if json_:
        print(json.dumps(report))
        return
    err.print(f"held-out PSNR {score:.2f} dB after {result.steps} steps, {result.wall_time_s:.0f} s "
              f"({result.rays_per_s:.0f} rays/s); wrote {out}/")


@_names("mesh")
def render_dataset(
    mesh: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="MESH")],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))],
    views: int = 100,
    size: int = 100,
    quiet: bool = False,
) -> None:
    """Render RGBA views of a mesh at known cameras with MuJoCo's renderer (headless) as a
    transforms.json image set: training data with exact ground truth.

    Args:
        mesh: a mesh file (.obj/.stl/.ply/...; its frame and units, taken as metres).
        out: the folder to write (transforms.json, images/r_NNN.png); must not exist or be empty.
        views: number of views (cameras on a Fibonacci sphere around the mesh).
        size: image width and height [px].
        quiet: no progress bar.
    """
    from .nerf.synthetic import render_dataset as render

    if not 1 <= views <= 10_000 or not 8 <= size <= 4096:
        raise ValueError(f"--views must be 1 to 10000 and --size 8 to 4096, got {views} and {size}")
    with _progress(not quiet) as progress:
        render(mesh, out, views=views, size=size, progress=progress)
    err.print(f"wrote {out}/transforms.json and {views} images of {size}x{size} px")


def _check_new_folder(out: Path) -> None:
    if out.exists() and (not out.is_dir() or any(out.iterdir())):
        raise ValueError(f"{out}: exists and is not an empty folder; choose a new output folder")


@_names("video")
def track(
    video: Annotated[Path, tyro.conf.Positional, tyro.conf.arg(metavar="VIDEO")],
    object: Annotated[str, tyro.conf.arg(metavar="FILE.dano|builtin:NAME")],
    pose: Annotated[tuple[float, float, float, float, float, float, float], tyro.conf.arg(metavar="X Y Z QW QX QY QZ")],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))],
    camera: Path | None = None,
    masks: Path | None = None,
    background: Path | None = None,
    subtract_background: bool = False,
    threshold: float = 0.08,
    fps: float | None = None,
    field: Path | None = None,
    colour_weight: float = 0.0,
    colour_rays: int = 1024,
    iterations: int = 60,
    stride: int = 2,
    smoothness_weight: float = 0.0,
    no_video: bool = False,
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    quiet: bool = False,
) -> None:
    """Track a DANO's pose through a video by fitting rendered silhouettes to masks (and colours).

    Args:
        video: a video folder (camera.json, frames/, optional masks/ and background.png), a folder of
            frames or a video file (then give --camera).
        object: the DANO tracked (a .dano file that stores its field, or builtin:NAME).
        pose: its body pose in the first frame (centre of mass [m], wxyz quaternion; world frame).
        out: folder to write poses.npz (a dano trajectory, ready for `dano sysid`), track.csv, overlay.mp4,
            report.json.
        camera: camera.json (intrinsics, transform_matrix camera-to-world, convention, fps).
        masks: folder of mask images (one per frame; white = object).
        background: the background frame (no object) for background subtraction.
        subtract_background: make masks from the background even where mask images exist.
        threshold: background subtraction's colour difference (0-1).
        fps: frames per second (default: camera.json's).
        field: a trained field directory (dano train-field) in the DANO's object frame, for the colour term.
        colour_weight: weight of the colour (photometric) term; needs --field.
        colour_rays: rays of the colour term per frame, drawn at random among those rendered (0: all).
        iterations: Adam steps per frame.
        stride: pixels per ray along each axis.
        smoothness_weight: weight of a prior toward the constant-velocity prediction.
        no_video: skip overlay.mp4.
        json_: print one JSON object (frames, poor_frames, mean_iou, time_per_frame_s, ...).
        quiet: no progress bar.
    """
    from .tracking import TrackConfig, TrackedObject, load_video, track as run_track, write_track_outputs

    _check_new_folder(out)
    config = TrackConfig(iterations=iterations, stride=stride, colour_weight=colour_weight,
                         smoothness_weight=smoothness_weight, colour_rays=colour_rays)
    radiance = radiance_occupancy = None
    if field is not None:
        from .nerf import load_field

        radiance, radiance_occupancy, _ = load_field(field)
    obj = TrackedObject.from_asset(load_asset(object), radiance, radiance_occupancy)
    data = load_video(video, camera=camera, masks=masks, background=background, fps=fps, threshold=threshold,
                      subtract_background=subtract_background)
    with _progress(not quiet and not json_) as progress:
        result = run_track(data, obj, pose, config, progress=progress)
    report = {**result.summary(), "video": str(video), "object": object, "initial_pose": list(pose)}
    rate = 1.0 / float(data.time[1] - data.time[0]) if data.num_frames > 1 else 1.0
    files = write_track_outputs(out, data, result, obj.name, report, rate, video_file=not no_video)
    if json_:
        print(json.dumps(report))
    else:
        err.print(f"tracked {report['frames']} frames ({report['poor_frames']} poor, mean IoU "
                  f"{report['mean_iou']:.3f}, {report['time_per_frame_s']:.2f} s per frame); wrote "
                  f"{', '.join(files)} in {out}")


def real2sim(
    task: Annotated[Literal["synthetic-slide"], tyro.conf.Positional, tyro.conf.arg(metavar="TASK")],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))] = Path("dano-real2sim"),
    friction: float = 0.35,
    no_video: bool = False,
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    quiet: bool = False,
) -> None:
    """From video to physics on a video with a known answer: poses -> friction and pixels -> friction.

    Args:
        task: synthetic-slide: the low-poly bunny slides and tumbles (MuJoCo renders the video from its mesh).
        out: folder to write video/ (frames, masks, background, camera.json, truth.npz) and track/ (poses.npz,
            track.csv, overlay.mp4, report.json).
        friction: the true sliding friction of the video.
        no_video: skip overlay.mp4.
        json_: print one JSON object (mu_true, mu_two_stage, mu_pixels, track_rms_mm, track_rms_deg,
            wall_time_s, ...).
        quiet: no progress bar.
    """
    from .experiments.real2sim import synthetic_slide_real2sim

    _check_new_folder(out)
    if not 0 < friction <= 1.5:
        raise ValueError(f"--friction must be in (0, 1.5], got {friction}")
    with _progress(not quiet and not json_) as progress:
        report = synthetic_slide_real2sim(out, friction, video_file=not no_video, progress=progress)
    brief = {k: v for k, v in report.items() if k != "per_frame"}
    if json_:
        print(json.dumps(_json_safe(brief)[0]))
    else:
        out.mkdir(exist_ok=True)
        err.print(f"mu: true {report['mu_true']:.4f}, two-stage {report['mu_two_stage']:.4f}, pixels "
                  f"{report['mu_pixels']:.4f}; tracking RMS {report['track_rms_mm']:.1f} mm, "
                  f"{report['track_rms_deg']:.2f} deg; {report['wall_time_s']:.0f} s; wrote {out}")


Collision = Literal["hull", "decomposition", "none"]


def _level_meshes(paths):
    """--mesh FILE (object frame) -> Level list (mesh files may be open, noisy level sets)."""
    from .io import load_mesh
    from .experiments.meshroute import Level

    levels = []
    for p in paths:
        label, eq, file = str(p).rpartition("=")
        path = Path(file)
        levels.append(Level(label if eq else path.stem, load_mesh(path, require_watertight=False), file=path.name))
    return levels


@_names("file")
def export(
    file: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="FILE.dano")],
    out: Annotated[Path, tyro.conf.arg(aliases=("-o",))],
    collision: Collision = "hull",
    level: float | None = None,
    mesh: Path | None = None,
    resolution: int = 96,
    threshold: float = 0.1,
    max_pieces: int = -1,
    name: str | None = None,
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
) -> None:
    """Export a DANO as a MuJoCo MJCF (.xml) or URDF (.urdf) body: its mass, centre of mass and full inertia,
    its visual mesh and collision geometry.

    Args:
        file: the .dano file (or builtin:NAME).
        out: OUT.xml (MJCF, one file, meshes inline) or OUT.urdf (plus OUT_meshes/ with OBJ files).
            The body frame is the DANO's (object axes, origin at the centre of mass).
        collision: 'hull' (convex hull of a level set), 'decomposition' (CoACD approximate convex
            decomposition of it) or 'none'.
        level: density of the level set to make collision geometry from (needs a stored field); default the
            asset's visual mesh.
        mesh: a level-set mesh (object frame) to use instead, e.g. the paper's bluesoap_level_70.stl.
        resolution: marching-cubes nodes along the longest axis for --level.
        threshold: CoACD concavity threshold (smaller: more, tighter pieces; slower).
        max_pieces: CoACD: merge down to at most this many pieces (-1: no limit).
        name: body/link name (default the asset's).
        json_: print a JSON summary (path, collision, pieces, mass, inertia) to stdout.
    """
    from .io import load_mesh
    from .io.exporters import EXPORT_SUFFIXES, Decomposition, body_meshes
    from .io.exporters import export as export_asset

    if out.suffix.lower() not in EXPORT_SUFFIXES:  # before any (possibly long) decomposition
        raise ValueError(f"-o {out}: unknown export format {out.suffix!r}; use .xml (MJCF) or .urdf (URDF)")
    if not 0 < threshold < float("inf"):
        raise ValueError(f"--threshold must be a positive number, got {threshold}")
    _check_resolution(resolution)
    asset = load_asset(file)
    given = load_mesh(mesh, require_watertight=False) if mesh is not None else None
    if given is not None and level is not None:
        raise ValueError("give either --level or --mesh, not both")
    meshes = body_meshes(asset, collision, level=level, mesh=given, resolution=resolution,
                         decomposition=Decomposition(threshold=threshold, max_pieces=max_pieces))
    export_asset(asset, out, meshes=meshes, name=name)
    summary = {"path": str(out), "format": "mjcf" if out.suffix.lower() == ".xml" else "urdf",
               "collision": collision, "collision_source": meshes.source, "pieces": len(meshes.collision),
               "mass": asset.mass, "inertia": asset.inertia.tolist()}
    if json_:
        print(json.dumps(summary))
    err.print(f"wrote {out} ({meshes.source if collision != 'none' else 'no collision geometry'})")


def _compare_table(report) -> Table:
    t = Table(title=f"mesh route vs DANO: {report['source']} (DANO rest height {report['dano']['rest_height']:.4f}, "
                    f"slide {report['dano']['slide_distance']:.4f})")
    for col in ("level", "collider", "comp.", "pieces", "CoM err", "inertia err", "rest Δz", "tilt [deg]",
                "slide diverg."):
        t.add_column(col)
    for e in report["levels"]:
        for c, r in e["collision"].items():
            t.add_row(e["label"], c, str(e["components"]), str(r["pieces"]), f"{r['com_error']:.4f}",
                      f"{100 * r['inertia_error']:.1f} %", f"{r['rest_height_error']:+.4f}",
                      f"{r['rest_tilt_deg']:.2f}", f"{r['slide_divergence']:.4f}")
    return t


@_names("source")
def compare_mesh(
    source: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="SOURCE")],
    levels: tuple[float, ...] = (),
    mesh: Annotated[tuple[str, ...], tyro.conf.UseAppendAction, tyro.conf.arg(metavar="[LABEL=]FILE")] = (),
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0),
    collision: tuple[Literal["hull", "decomposition"], ...] = ("hull", "decomposition"),
    friction: float = 0.2,
    slide_speed: float = 1.0,
    rest_time: float = 3.0,
    slide_time: float = 2.0,
    resolution: int = 96,
    threshold: float = 0.1,
    max_pieces: int = -1,
    contact_model: str = "centroid",
    figure: Path | None = None,
    out: Path | None = None,
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False,
    quiet: bool = False,
) -> None:
    """Level-set meshes of a density field as MuJoCo colliders (convex hull, CoACD decomposition) against the
    DANO: mesh pieces, mass-property errors, rest height and tilt, slide divergence (docs/mesh-route.md).

    Args:
        source: a .dano file (or builtin:NAME, e.g. builtin:bluesoap for the paper's real soap).
        levels: densities whose level sets are extracted from the stored field (marching cubes).
            With --mesh, both are compared.
        mesh: a level-set mesh file in the object frame, FILE or LABEL=FILE (e.g. the paper's
            bluesoap_level_70.stl); repeat the option for several. Default, when neither --levels nor --mesh
            is given: 0.1, 0.5 and 0.9 of the field's interior density, or the asset's visual mesh if it has
            no field.
        quat: orientation w x y z of the drop (object axes in the world).
        collision: collider kinds to build.
        friction: sliding friction in both engines (Coulomb only).
        slide_speed: initial speed of the slide [m/s].
        rest_time: settling time of the drop [s].
        slide_time: duration of the slide [s].
        resolution: marching-cubes nodes along the longest axis.
        threshold: CoACD concavity threshold.
        max_pieces: CoACD: merge down to at most this many pieces (-1: no limit).
        contact_model: dano's contact model for the DANO.
        figure: write renders of every collider at rest (like the paper's Fig. 8) to this image.
        out: also write the JSON report to this file.
        json_: print the report as one JSON object instead of a table.
        quiet: no progress bar.
    """
    from contextlib import ExitStack

    from ._files import atomic_path
    from .io.exporters import Decomposition
    from .experiments.meshroute import Scenario, compare_mesh as run, default_levels, extract_levels, render_rest_figure

    _check_contact_model(contact_model)
    _check_resolution(resolution)
    if not 0 < threshold < float("inf"):  # the scenario's own values are checked by ScenarioConfig
        raise ValueError(f"--threshold must be a finite positive number, got {threshold}")
    asset = load_asset(source)
    lv = _level_meshes(mesh) + (extract_levels(asset, levels, resolution) if levels else [])
    lv = lv or default_levels(asset, resolution)
    scenario = Scenario(quat=quat, friction=friction, rest_time=rest_time, slide_time=slide_time,
                        slide_speed=slide_speed)
    with _progress(not quiet) as progress:
        report = run(asset, lv, collisions=collision, scenario=scenario, contact_model=contact_model,
                     decomposition=Decomposition(threshold=threshold, max_pieces=max_pieces), progress=progress)
    with ExitStack() as stack:  # the figure and the report: both or neither
        if figure is not None:
            render_rest_figure(asset, report, stack.enter_context(atomic_path(figure)), levels=lv)
        report.pop("_models")
        if out is not None:
            stack.enter_context(atomic_path(out)).write_text(json.dumps(report, indent=1))
    for path in (figure, out):
        if path is not None:
            err.print(f"wrote {path}")
    text = json.dumps(report)
    if json_:
        print(text)
    else:
        Console().print(_compare_table(report))  # (the console `out` is shadowed by the option)


def _check_contact_model(name: str) -> None:
    """--contact-model: raises ValueError (a clean CLI error) for an unknown model name."""
    from .contact import CONTACT_MODELS

    if name not in CONTACT_MODELS:
        raise ValueError(f"unknown --contact-model {name!r}; available: {', '.join(CONTACT_MODELS)}")


COMMANDS = {"build": build, "inspect": inspect, "simulate": simulate, "sysid": sysid, "export": export,
            "compare-mesh": compare_mesh, "trajopt": trajopt, "train-field": train_field,
            "render-dataset": render_dataset, "track": track, "real2sim": real2sim, "demo": demo, "bench": bench}


def _terminate(signum, frame):
    raise SystemExit(128 + signum)


# options that take several values after one flag; tyro would keep only the last repetition
_MULTI_VALUE_FLAGS = ("--object", "--param", "--levels", "--collision", "--suite", "--eval-at", "--bounds", "--pose")


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

    if "NPROC" not in os.environ and not _jax_setup._backend_started() and not _wide(args):
        os.environ["NPROC"] = "1"
    _jax_setup.enable_float64()
    _jax_setup.enable_compilation_cache()
    import mujoco
    from rich.markup import escape

    # MuJoCo's own warnings become dano's messages instead of MUJOCO_LOG.TXT in the working folder
    mujoco.set_mju_user_warning(lambda msg: err.print(f"[yellow]warning:[/] MuJoCo: {escape(msg)}", highlight=False,
                                                      soft_wrap=True))
    # SIGTERM unwinds like Ctrl-C: temporary files are removed, no partial output is left
    signal.signal(signal.SIGTERM, _terminate)
    # Python warnings (numpy, JAX, MJX): one line each, like dano's own messages
    import warnings

    warnings.showwarning = lambda message, category, *rest: err.print(
        f"[yellow]warning:[/] {category.__name__}: {escape(' '.join(str(message).split()))}", highlight=False,
        soft_wrap=True)


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``dano`` console script; returns the exit code."""
    from . import __version__
    from .errors import DanoError

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
        tyro.extras.subcommand_cli_from_dict(COMMANDS, args=args, prog="dano",
                                             description="Dynamics-augmented neural objects (DANOs).")
    except SystemExit as exc:  # tyro's own parse errors and --help
        return int(exc.code or 0)
    except KeyboardInterrupt:
        err.print("[bold red]interrupted[/]", highlight=False)
        return 130
    except Exception as exc:
        if debug:
            raise
        from rich.markup import escape

        known = isinstance(exc, (DanoError, ValueError, OSError))
        text = _error_line(exc) if known else (f"internal error ({type(exc).__name__}: {_error_line(exc)}); "
                                               "please report it, with the output of --debug")
        err.print(f"[bold red]error:[/] {escape(text)}", highlight=False, soft_wrap=True)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
