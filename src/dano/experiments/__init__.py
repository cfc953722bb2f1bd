"""The paper's reproductions and dano's studies, as named experiments built on the library.

The library (``dano.fields`` … ``dano.tracking``) never imports this package; the command
line resolves built-in names through :data:`EXPERIMENTS` (``dano sysid soap``, ``dano
trajopt push-sphere``, ``dano real2sim synthetic-slide``), and ``dano bench`` runs the
studies. Each experiment is registered here with the verb that runs it, a one-line
summary, its typed configuration class (a frozen dataclass, or None when it takes no
settings) and the function that runs it, imported only when it runs (in the spirit of
nerfstudio's ``method_configs``).

Modules: :mod:`.sysid_examples` (the soap video, the bunny pushes, the ContactNets cube,
coverage studies), :mod:`.mujoco_c` (slides recorded in plain MuJoCo C), :mod:`.push` and
:mod:`.grasp` (the push and grasp tasks), :mod:`.trajopt_run` (their runs and outputs),
:mod:`.slide` and :mod:`.real2sim` (the synthetic slide video and video → physics),
:mod:`.nerf_loop` (the NeRF ground-truth loop), :mod:`.meshroute` (DANO vs mesh, the paper's
Fig. 8), :mod:`.energy` (random drops and the energy check), :mod:`.tracking_curves`
(tracking success curves).
"""

from __future__ import annotations

import functools
import importlib
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Callable

import tyro

from .._config import read_table
from .._files import json_safe
from ..errors import DanoError, FileFormatError


@dataclass(frozen=True)
class Experiment:
    """A registered experiment.

    name: its built-in name (``soap``); verb: the ``dano`` verb that runs it (``sysid``);
    summary: one line for help texts; runner: ``"module:function"`` inside this package;
    config: ``"module:Class"`` of its typed configuration, or None.
    """

    name: str
    verb: str
    summary: str
    runner: str
    config: str | None = None

    def _load(self, ref: str):
        module, attr = ref.split(":")
        return getattr(importlib.import_module(f"{__name__}.{module}"), attr)

    @property
    def run(self) -> Callable:
        """The function that runs it (its module imported now)."""
        return self._load(self.runner)

    @property
    def config_class(self) -> type | None:
        """Its configuration class (its module imported now), or None."""
        return None if self.config is None else self._load(self.config)


_ALL = (
    Experiment("soap", "sysid", "friction of the paper's real soap video (bluesoap collider, 120 fps)",
               "sysid_examples:run_example"),
    Experiment("bunny-pushes", "sysid", "the bunny's mass scale and friction from 10 simulated pushes",
               "sysid_examples:run_example"),
    Experiment("bunny-dynamics", "sysid", "the same pushes with the bunny's centre of mass and inertia unknown too",
               "sysid_examples:run_example"),
    Experiment("contactnets-cube", "sysid", "real cube tosses (ContactNets): fit half, predict the other half",
               "sysid_examples:run_contactnets", "sysid_examples:ContactNetsConfig"),
    Experiment("push-sphere", "trajopt", "the paper's Fig. 7: a floating sphere pushes the bunny to a goal",
               "trajopt_run:run", "push:PushSphereConfig"),
    Experiment("push-panda", "trajopt", "the Panda's joint torques push the bunny to a goal",
               "trajopt_run:run", "push:PushPandaConfig"),
    Experiment("push", "trajopt", "a floating sphere, sized to the object, pushes any DANO to a goal",
               "trajopt_run:run", "push:PushObjectConfig"),
    Experiment("grasp-panda", "trajopt", "the Panda's hand grasps, lifts and holds the bunny",
               "trajopt_run:run", "grasp:GraspPandaConfig"),
    Experiment("synthetic-slide", "real2sim", "a rendered slide video -> poses -> friction, and pixels -> friction",
               "real2sim:synthetic_slide_real2sim"),
)

#: every registered experiment, by (verb, name)
EXPERIMENTS: dict[tuple[str, str], Experiment] = {(e.verb, e.name): e for e in _ALL}


def names(verb: str) -> tuple[str, ...]:
    """The built-in names a verb resolves (``names("sysid")`` → soap, bunny-pushes, ...)."""
    return tuple(name for v, name in EXPERIMENTS if v == verb)


def get(verb: str, name: str) -> Experiment:
    """The experiment ``name`` of ``verb``. Raises DanoError listing the verb's names."""
    try:
        return EXPERIMENTS[(verb, name)]
    except KeyError:
        raise DanoError(f"unknown {verb} experiment {name!r}: one of {', '.join(names(verb))}") from None


def is_experiment(verb: str, name: str) -> bool:
    """Whether ``name`` is a built-in experiment of ``verb`` (else a file, e.g. a TOML problem)."""
    return (verb, name) in EXPERIMENTS


def run_sysid(name: str, **options):
    """Run a built-in identification: ``soap``, ``bunny-pushes``, ``bunny-dynamics``
    (options ``jacobian``, ``noise``, ``sensitivity``, ``defer_studies``: :func:`~dano.experiments.sysid_examples.run_example`) or ``contactnets-cube`` (options of
    :class:`~dano.experiments.sysid_examples.ContactNetsConfig`). Returns (problem, result,
    {"report", "config"}) as :func:`dano.sysid.config.run`."""
    exp = get("sysid", name)
    if exp.config is None:
        return exp.run(name, **options)
    return exp.run(exp.config_class(**options))


@dataclass(frozen=True)
class SysIdCommandConfig:
    """Identify friction and mass scale from observed trajectories (Gauss-Newton/LM with AD Jacobians)."""

    config: Annotated[str | None, tyro.conf.Positional, tyro.conf.arg(metavar="CONFIG")] = None
    """a TOML problem file, or a built-in example: soap (the paper's real soap video), bunny-pushes (the
    paper's bunny pushed 10 times by a sphere), bunny-dynamics (the same pushes with the bunny's centre of
    mass and inertia unknown as well), contactnets-cube (real cube tosses: friction, impact spring and
    damper and the table height on half the tosses, the other half predicted; needs --data)."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (estimates as top-level keys, e.g. sliding_friction, with <name>_std, wall_time_s,
    compile_time_s, cost_history, ...)."""
    out_dir: Annotated[Path | None, tyro.conf.arg(name="out", aliases=("-o", "--out-dir"))] = None
    """write result.json, config.json (the resolved configuration) and fit.png here (default: sysid-<name>/)."""
    jacobian: str | None = None
    """ad (forward-mode AD, default) or fd (finite differences, for comparison)."""
    no_noise: bool = False
    """bunny-pushes, bunny-dynamics: observations without the 1 mm / 0.5 deg pose noise."""
    no_sensitivity: bool = False
    """soap: leave out the length-scale sensitivity study (two more identifications beside the result, about
    0.1 s warm, run while the fit is drawn; JSON key length_scale_sensitivity)."""
    data: Path | None = None
    """contactnets-cube: the ContactNets tosses (.npz of toss_<n> arrays, (T, 13) each; not shipped with dano,
    e.g. shared/data/real/contactnets_cube/tosses_100_299.npz)."""
    tosses: int = 10
    """contactnets-cube: use the first this many tosses (even ones fitted, odd ones held out)."""
    start: float = 0.3
    """contactnets-cube: initial guess of the sliding friction."""
    contact_model: str = "centroid"
    """contactnets-cube: centroid (the paper's) or per_sample."""
    template: Annotated[tuple[str, ...], tyro.conf.arg(metavar="[SCENE.xml] OBJECT.dano")] = ()
    """instead of identifying: print a commented TOML problem for your MJCF scene (optional) and objects (e.g.
    `dano sysid --template scene.xml spot.dano > problem.toml`), then fill in the trajectory files."""
    bootstrap: int = 0
    """contactnets-cube: also refit this many resamples of the fitted tosses (with replacement) for a 95 %
    interval, key "bootstrap" of the JSON (TOML problems: [options] bootstrap)."""
    devices: int | None = None
    """local devices that the identification splits its trajectories (residual and Jacobian) and its scan's
    parameter vectors over (default: all of this process's; the estimate is the same; docs/scaling.md)."""

    def __post_init__(self):
        if self.config is None and not self.template:
            raise DanoError("give a CONFIG (a TOML problem, a saved config.json or a built-in example) or --template")
        if self.devices is not None:
            from ..sharding import check_devices  # (starts JAX: only when asked)

            check_devices(self.devices, "--devices")

    def resolved(self) -> SysIdCommandConfig:
        """The configuration to run: a saved ``config.json`` of a built-in example becomes that
        example with its saved settings (options given explicitly are kept)."""
        import dataclasses

        path = Path(str(self.config))
        if not (str(self.config).lower().endswith(".json") and path.is_file()):
            return self
        saved = read_table(path)
        if saved.get("example") == "contactnets-cube":  # rerun what a contactnets-cube run saved
            return dataclasses.replace(
                self, config="contactnets-cube", data=self.data or Path(str(saved.get("data", ""))),
                tosses=int(saved.get("tosses", self.tosses)), start=float(saved.get("start", self.start)),
                contact_model=str(saved.get("contact_model", self.contact_model)),
                bootstrap=int(saved.get("bootstrap", self.bootstrap)))
        if "example" in saved:  # the config.json of a built-in example reruns it
            if not is_experiment("sysid", saved["example"]):
                raise FileFormatError(f"{path}: unknown example {saved['example']!r}; one of "
                                      f"{', '.join(names('sysid'))}")
            noise_saved = saved.get("noise", {})
            no_noise = self.no_noise or (isinstance(noise_saved, dict) and noise_saved.get("position_m") == 0)
            no_sensitivity = self.no_sensitivity or saved.get("sensitivity") is False
            return dataclasses.replace(self, config=saved["example"], no_noise=no_noise, no_sensitivity=no_sensitivity)
        return self


def _withheld_with_reason(key: str, result) -> bool:
    """Whether the report's null ``key`` is a standard error that the identification
    ``result`` withholds for a reason its warnings give: every one where the solver stopped
    short of a converged minimum (``success`` false), or its global parameter's where that
    sits at a bound, is bounded on one side only or has a rough cost (``identifiability``)."""
    if key.startswith("standard_errors."):
        label = key[len("standard_errors."):]
    elif key.endswith("_std"):
        label = key[: -len("_std")]
    else:
        return False
    status = (result.identifiability or {}).get(label, {}).get("status")
    return not result.success or status in ("at bound", "one-sided", "rough")


def sysid_command(config: SysIdCommandConfig):
    """``dano sysid``: a built-in example (:func:`run_sysid`), a TOML problem or a saved
    ``config.json`` (:func:`dano.sysid.config.run`), its outputs written to ``out_dir``
    (default ``sysid-<name>/``: :func:`dano.sysid.outputs.write_outputs`). Returns
    (problem, result, report, out_dir): the report as written, non-finite values as null
    and listed in its ``warnings``. Raises DanoError for an unknown name or a bad file."""
    # the registry stays light (no MuJoCo, no JAX) until an identification runs
    from ..sharding import use_devices
    from ..sysid.config import run
    from ..sysid.outputs import write_outputs

    with use_devices(config.devices, "--devices"):
        return _sysid_command(config, run, write_outputs)


def _sysid_command(config: SysIdCommandConfig, run, write_outputs):
    import jax

    c = config.resolved()
    if c.config == "contactnets-cube":
        if c.data is None:
            raise DanoError("contactnets-cube needs --data: the ContactNets tosses .npz (arrays toss_<n>, not "
                            "shipped with dano)")
        problem, result, out = run_sysid(c.config, data=c.data, tosses=c.tosses, start=c.start,
                                         contact_model=c.contact_model, bootstrap=c.bootstrap)
    elif is_experiment("sysid", c.config):
        # the studies beside the result (the soap's length-scale sensitivity) run while the fit is drawn
        problem, result, out = run_sysid(c.config, jacobian=c.jacobian, noise=not c.no_noise,
                                         sensitivity=not c.no_sensitivity, defer_studies=True)
    else:
        if Path(c.config).suffix.lower() not in (".toml", ".json") and not Path(c.config).exists():
            raise DanoError(f"unknown identification {c.config!r}: give a TOML file, a saved config.json or one of "
                            f"{', '.join(names('sysid'))}")
        problem, result, out = run(c.config, jacobian=c.jacobian)
    name = c.config if c.config == "contactnets-cube" else config.config
    out_dir = c.out_dir or Path(f"sysid-{Path(name).stem}")
    with ThreadPoolExecutor(max_workers=1) as pool:
        pending = {key: pool.submit(study) for key, study in out.get("studies", {}).items()}

        @functools.cache
        def final_report() -> dict:
            raw = {**out["report"], **{key: f.result() for key, f in pending.items()}}
            report, nonfinite = json_safe(raw)
            notes = list(report.get("warnings", result.warnings))
            withheld = [k for k in nonfinite if _withheld_with_reason(k, result)]
            unknown = [k for k in nonfinite if k not in withheld]
            if withheld:
                from ..sysid.problem import SEGMENT_NUISANCE_PREFIXES

                starts = [k for k in withheld if any(p in k for p in SEGMENT_NUISANCE_PREFIXES)]
                named = ", ".join(k for k in withheld if k not in starts)
                counted = f"the standard errors of {len(starts)} start-state offsets" if starts else ""
                notes.append(f"withheld (written as null): {' and '.join(x for x in (named, counted) if x)}, for the "
                             "reasons the warnings above give")
            if unknown:
                notes.append(f"not finite (written as null): {', '.join(unknown)}; the data do not determine these "
                             "(check that positions are in metres and that the motion excites the parameters)")
            report["warnings"] = notes
            return report

        if jax.process_index() == 0:  # a multi-process run (docs/scaling.md): every process has the result
            write_outputs(out_dir, final_report, out["config"], problem, result)
        report = final_report()
    return problem, result, report, out_dir


__all__ = ["EXPERIMENTS", "Experiment", "SysIdCommandConfig", "get", "is_experiment", "names", "run_sysid",
           "sysid_command"]
