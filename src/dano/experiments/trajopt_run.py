"""``dano trajopt``'s work as library calls: read a task or configuration, solve, report and
write every output (all or none)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import json
from contextlib import ExitStack
from pathlib import Path
from typing import Annotated

import numpy as np
import tyro

from .._config import read_table, typed_table
from .._files import atomic_path, config_json, json_safe
from .._threads import in_background
from ..contact import CONTACT_MODELS
from ..errors import DanoError
from ..sim import SimulationDiverged, State, rollout
from ..sim.run import absolute_source
from ..trajectory import Trajectory
from ..viz.plot import plot_trajopt
from ..viz.video import check_mujoco_video, write_video
from .grasp import GraspPandaConfig, run_grasp
from .push import (TASKS, final_errors, first_guess, limit_report, model_error_run, pusher_positions, reach_warnings,
                   solve_task)

#: every built-in task: name -> its configuration class
CONFIGS = {**{name: cls for name, (_, cls) in TASKS.items()}, "grasp-panda": GraspPandaConfig}


def load_config(source: str, **overrides):
    """The task configuration: a built-in task name or a TOML/JSON file (key ``task`` and
    the task's settings), with ``overrides`` (None values ignored) applied and validated.
    Raises DanoError for an unknown task, unknown keys, wrong types or values out of range."""
    base = Path.cwd()  # where a relative object path given on the command line is
    if source in CONFIGS:
        cfg = CONFIGS[source]()
    else:
        path = Path(source)
        if path.suffix.lower() not in (".toml", ".json") and not path.exists():
            raise DanoError(f"unknown task {source!r}; built-in tasks: {', '.join(CONFIGS)} (or a TOML/JSON config)")
        raw = read_table(path)
        name = raw.get("task")
        if name not in CONFIGS:
            raise DanoError(f"{path}: [task] must name a built-in task ({', '.join(CONFIGS)}), got {name!r}")
        try:
            cfg = typed_table(raw, CONFIGS[name], "")
        except DanoError as exc:
            raise DanoError(f"{path}: {exc}") from None
        cfg = _absolute(cfg, path.parent)  # (a relative path in the file: relative to the file's folder)
    given = {k: v for k, v in overrides.items() if v is not None}
    unused = sorted(set(given) - {f.name for f in dataclasses.fields(cfg)})
    if unused:
        raise DanoError(f"{cfg.task} does not use {', '.join('--' + k.replace('_', '-') for k in unused)}")
    return _absolute(dataclasses.replace(cfg, **given), base)  # checked as it is built


def _absolute(cfg, base: Path):
    """``cfg`` with its object file (``push``'s ``object``, unless ``builtin:NAME``) made
    absolute against ``base``, so that the ``config.json`` a run saves reruns from any folder."""
    obj = getattr(cfg, "object", None)
    return cfg if obj is None else dataclasses.replace(cfg, object=absolute_source(obj, base))


def report(task, solution, model_error=None) -> dict:
    """The JSON report: ``bunny_final_error`` (also ``object_final_error``: the pushed
    object, whatever it is), ``pusher_final_error`` [m] (null for a pusher without a goal),
    ``max_constraint_violation``, ``iterations``, ``converged``, ``status``, ``cost``,
    ``wall_time_s``, ``compile_time_s``, ``plain_push_bunny_final`` (where the plain push
    leaves the bunny; also ``plain_push_object_final``: the pushed object, whatever it is), goals,
    ``object_final_speed`` [m/s] (the pushed object's x–y speed
    at the last step: above 0 it slides on past where it is), ``replay_final_gap`` [qpos units: m
    for positions] (the largest qpos difference at the last step between the plan's states and the scene's own
    rollout of its controls, :func:`replay`; null where that rollout diverges: above 1e-6, or
    null, a warning in ``warnings`` says the plan does not hold in simulation),
    ``max_control_ratio`` and (arm)
    ``joint_limit_violation``, ``first_guess`` (:func:`~dano.experiments.push.first_guess`), ``restarts`` (the
    other solves of the problem, not kept: guess, status, iterations, max_violation) and,
    with a model error, ``model_error``: world friction,
    open-loop and receding-horizon final errors."""
    eb, ep = final_errors(task, solution.states)
    X = np.asarray(solution.states)
    v0 = task.scene.nq + int(task.scene.dof_adr[0])
    again, gap = replay(task, X, np.asarray(solution.controls))
    out = {
        "task": task.config.task, "bunny_final_error": eb, "pusher_final_error": ep,
        "max_constraint_violation": solution.max_violation, "iterations": solution.iterations,
        "converged": solution.converged, "status": solution.status, "cost": solution.cost,
        "wall_time_s": solution.wall_time_s, "compile_time_s": solution.compile_time_s,
        "bunny_goal": task.bunny_goal.tolist(),
        "object_final_error": eb, "object_goal": task.bunny_goal.tolist(),  # the same, for any object
        "pusher_goal": None if task.pusher_goal is None else task.pusher_goal.tolist(),
        "plain_push_bunny_final": task.X_plain[-1, task.bunny_qpos].tolist(),
        "plain_push_object_final": task.X_plain[-1, task.bunny_qpos].tolist(),  # the same, for any object
        "object_final_speed": float(np.linalg.norm(X[-1, v0:v0 + 2])),
        "replay_final_gap": None if again is None else gap,
        "horizon": task.problem.horizon, "dt": task.scene.dt,
        "first_guess": first_guess(solution), "restarts": list(solution.restarts),
        **limit_report(task, solution.states, solution.controls),
        "warnings": reach_warnings(task) + ([] if not gap > REPLAY_TOLERANCE else [
            "the plan does not hold in simulation: the scene's own rollout of its controls "
            + ("diverges" if again is None else f"ends {gap:.3g} m from the plan's states")
            + " (the video shows the plan); the solve has not found a physical plan (its status: "
            + solution.status + "): try a nearer goal or a longer horizon"]),
    }
    if model_error is not None:
        rh = model_error.receding
        ob, op = final_errors(task, model_error.open_loop_states)
        rb, rp = final_errors(task, rh.states)
        out["model_error"] = {
            "world_sliding_friction": model_error.friction, "model_sliding_friction": task.config.sliding_friction,
            "open_loop_bunny_final_error": ob, "open_loop_pusher_final_error": op,
            "receding_horizon_bunny_final_error": rb, "receding_horizon_pusher_final_error": rp,
            "replans": len(rh.replan_steps), "replan_every": task.config.replan_every,
            "replan_statuses": [s.status for s in rh.solves], "wall_time_s": rh.wall_time_s,
        }
    return out


def run(source: str, progress=None, **overrides):
    """Build and solve the task (and the model-error runs if configured). progress:
    optional ``progress(done, total, description)``. Returns (task, solution,
    model_error or None, report dict); for ``grasp-panda`` (task, the chosen
    :class:`~dano.experiments.grasp.GraspRun`, None, report)."""
    cfg = load_config(source, **overrides)
    if isinstance(cfg, GraspPandaConfig):
        task, chosen, rep = run_grasp(cfg, progress=progress)
        return task, chosen, None, rep
    build = TASKS[cfg.task][0]
    if progress is not None:
        progress(0, 1, "building the task")
    task = build(cfg)
    if progress is not None:
        progress(1, 1, "building the task")
    cb = None if progress is None else (lambda e: progress(e["iteration"], cfg.max_iterations,
                                                             f"iLQR (violation {e['max_violation']:.2g})"))
    # the report's replay (the scene's own rollout of the plan's controls) compiles while the
    # solver runs: the plain push has the plan's shapes
    replayed = in_background(lambda: replay(task, task.X_plain, task.U_plain))
    solution = solve_task(task, callback=cb)
    replayed()
    me = None
    if cfg.model_error > 0:
        T = task.problem.horizon
        me = model_error_run(task, solution, callback=None if progress is None else (
            lambda k, s: progress(k, T, "receding horizon")))
    return task, solution, me, report(task, solution, me)


def write_outputs(task, solution, model_error, rep: dict, out_dir: Path, video: bool = True, progress=None) -> list:
    """Write ``report.json``, ``config.json`` (the resolved configuration), ``solution.npz``
    (time (T+1,) [s], states (T+1, nx), controls (T, nu), qpos, qvel, gains, the plain push
    (the first guess, or twice it: the report's ``first_guess``), the goals and, with a model error, the world's open-loop and receding-horizon states),
    ``log.csv`` (the iteration log), ``convergence.png`` and, if ``video``, ``<task>.mp4``
    into ``out_dir``: all published together, or none. Returns the paths."""
    if isinstance(task.config, GraspPandaConfig):
        return _write_grasp(task, solution, rep, Path(out_dir), video, progress)
    out_dir = Path(out_dir)
    names = ["report.json", "config.json", "solution.npz", "log.csv", "convergence.png"]
    if video:
        names.append(f"{task.config.task}.mp4")
    X, U = np.asarray(solution.states), np.asarray(solution.controls)
    nq = task.scene.nq
    arrays = dict(time=np.arange(len(X)) * task.scene.dt, states=X, controls=U, qpos=X[:, :nq], qvel=X[:, nq:],
                  gains=np.asarray(solution.gains), plain_states=task.X_plain, plain_controls=task.U_plain,
                  bunny_goal=task.bunny_goal, object_goal=task.bunny_goal)  # (the same: any object)
    if task.pusher_goal is not None:
        arrays["pusher_goal"] = task.pusher_goal
    if model_error is not None:
        arrays.update(open_loop_world_states=model_error.open_loop_states,
                      receding_states=model_error.receding.states, receding_controls=model_error.receding.controls)
    log = solution.log
    keys = list(log)
    csv = ",".join(keys) + "\n" + "".join(",".join(f"{log[k][i]:.10g}" for k in keys) + "\n"
                                          for i in range(len(log[keys[0]])))
    with ExitStack() as stack:
        paths = {n: stack.enter_context(atomic_path(out_dir / n)) for n in names}
        _write_report_and_config(paths, rep, task.config)
        with open(paths["solution.npz"], "wb") as f:
            np.savez(f, **arrays)
        paths["log.csv"].write_text(csv)
        _plot(task, solution, model_error, paths["convergence.png"])
        if video:  # the plan's states: the report's replay found the scene's own rollout of its
            # controls within REPLAY_TOLERANCE of them, or warned that it is not (replay_final_gap)
            write_video(task.scene, _plan_trajectory(task.scene, X), paths[f"{task.config.task}.mp4"],
                        progress=progress)
    return [out_dir / n for n in names]


def _plot(task, solution, model_error, path) -> None:
    """convergence.png: the solver's log and the paths of the plain push, the plan and,
    with a model error, the open-loop and receding-horizon runs (:func:`dano.viz.plot_trajopt`)."""
    runs = [("plain push", task.X_plain, ":"), ("optimised", np.asarray(solution.states), "-")]
    if model_error is not None:
        runs += [(f"open loop, μ={model_error.friction:.3g}", model_error.open_loop_states, "--"),
                 ("receding horizon", model_error.receding.states, "-.")]
    pushed = "object" if task.config.task == "push" else "bunny"  # (push: any object)
    paths = [(f"{pushed}, {label}", X[:, task.bunny_qpos][:, :2], pusher_positions(task, X)[:, :2], style)
             for label, X, style in runs]
    goals = [(f"{pushed} goal", task.bunny_goal, "k*")]
    if task.pusher_goal is not None:
        goals.append(("pusher goal", task.pusher_goal, "kx"))
    plot_trajopt(solution.log, solution.status, solution.iterations, paths, path, goals=goals)


def _write_report_and_config(paths: dict, rep: dict, config) -> None:
    paths["report.json"].write_text(json.dumps(rep, indent=2))
    paths["config.json"].write_text(config_json(dataclasses.asdict(config)))


#: the largest qpos difference [m] at the last step between a plan's states and the scene's own
#: rollout of its controls that counts as the same motion
REPLAY_TOLERANCE = 1e-6


def replay(task, X, U):
    """The scene's own rollout of a push task's controls U (T, nu) from the states X (T + 1,
    nx)'s first: (a :class:`~dano.trajectory.Trajectory` or None where that rollout diverges,
    the largest qpos difference at the last step from X's [qpos units], inf if it diverges)."""
    qfrc = None
    if task.apply == "qfrc":
        qfrc = np.zeros((len(U), task.scene.nv))
        qfrc[:, task.control_dofs] = U
        U = None
    return _replayed(task.scene, task.params, X, U, qfrc)


def _replayed(scene, params, X, U, qfrc=None):
    """:func:`~dano.sim.rollout` of the controls U (T, nu) (or the generalised forces qfrc
    (T, nv)) from the states X (T + 1, nx)'s first, and its largest qpos difference from X's at
    the last step; (None, inf) where it diverges."""
    nq = scene.nq
    try:
        traj = rollout(scene, State(X[0, :nq], X[0, nq:]), U, params, len(X) - 1, qfrc=qfrc)
    except SimulationDiverged:
        return None, np.inf
    return traj, float(np.abs(traj.qpos[-1] - X[-1, :nq]).max())


def _plan_trajectory(scene, X) -> Trajectory:
    """The plan's states X (T + 1, nx) as a trajectory of ``scene`` (for its video)."""
    nq = scene.nq
    return Trajectory(time=np.arange(len(X)) * scene.dt, qpos=X[:, :nq], qvel=X[:, nq:],
                      psi=np.zeros((len(X), len(scene.pairs))), body_names=scene.body_names,
                      dano_names=scene.dano_names, qpos_adr=scene.qpos_adr, dof_adr=scene.dof_adr,
                      pair_names=scene.pair_names, metadata={"scene": scene.name, "dt": scene.dt})


def _replay_video(scene, params, X, U, path: Path, progress) -> None:
    """Replay the controls U (T, nu) from X[0] (:func:`_replayed`) and render the video to
    ``path``; raises DanoError if the replay does not end where the states X (T + 1, nx) do
    (:data:`REPLAY_TOLERANCE`)."""
    traj, gap = _replayed(scene, params, X, U)
    if gap > REPLAY_TOLERANCE:
        raise DanoError(f"internal: the replayed controls end {gap:.3g} m from the computed states")
    write_video(scene, traj, path, progress=progress)


def _write_grasp(task, run, rep: dict, out_dir: Path, video: bool, progress) -> list:
    """grasp-panda's outputs: report.json, config.json, solution.npz (time, states,
    controls, qpos, qvel, the joint waypoints, the grasp and, when optimised, the approach
    plan: approach_states, approach_controls at approach_dt) and the video, all or none."""
    names = ["report.json", "config.json", "solution.npz"] + (["grasp-panda.mp4"] if video else [])
    X, U = np.asarray(run.states), np.asarray(run.controls)
    nq = task.scene.nq
    g = task.grasp
    with ExitStack() as stack:
        paths = {n: stack.enter_context(atomic_path(out_dir / n)) for n in names}
        _write_report_and_config(paths, rep, task.config)
        with open(paths["solution.npz"], "wb") as f:
            a = task.approach
            plan = {} if a is None else dict(approach_states=a.states, approach_controls=a.controls, approach_dt=a.dt)
            np.savez(f, time=np.arange(len(X)) * task.scene.dt, states=X, controls=U, qpos=X[:, :nq],
                     qvel=X[:, nq:], waypoints=task.waypoints, grasp_center=g.center, grasp_axis=g.axis, **plan)
        if video:
            _replay_video(task.scene, task.params, X, U, paths["grasp-panda.mp4"], progress)
    return [out_dir / n for n in names]


@dataclass(frozen=True)
class TrajoptCommandConfig:
    """Optimise a robot motion through contact (constrained iLQR with an augmented Lagrangian)."""

    task: Annotated[str, tyro.conf.Positional, tyro.conf.arg(metavar="TASK|CONFIG")]
    """a built-in task (push: a sphere sized to the object pushes any DANO (--object) to --goal; push-sphere:
    the paper's sphere pushing the bunny 1.0 sideways of a plain push; push-panda: the Menagerie Panda's joint
    torques pushing a 15 cm bunny 10 cm, needs MENAGERIE_ROOT; grasp-panda: the Panda's hand grasps, lifts and
    holds the 15 cm bunny, needs MENAGERIE_ROOT) or a TOML/JSON configuration (key task and the task's settings, e.g. the config.json a run saved)."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (object_final_error (also bunny_final_error), object_final_speed, replay_final_gap,
    pusher_final_error, max_constraint_violation, iterations, converged, status, wall_time_s, compile_time_s,
    warnings, ...; model_error with --model-error; grasp-panda:
    lift_height, slip_mm, slip_deg, grip_force, converged, wall_time_s, contact_models, ...)."""
    out_dir: Annotated[Path | None, tyro.conf.arg(name="out", aliases=("-o", "--out-dir"))] = None
    """write report.json, config.json, solution.npz, log.csv, convergence.png and the video here (default:
    trajopt-<task>/)."""
    model_error: float | None = None
    """also run the plan in a world with (1 + this) times the sliding friction: open loop and with receding
    horizon (e.g. 0.3)."""
    max_iterations: int | None = None
    """iLQR iterations in all (default 300)."""
    contact_model: str | None = None
    """DANO contact model: centroid (the paper's, default) or per_sample."""
    sliding_friction: float | None = None
    """the sliding friction μ of the task's contact pairs (default: the task's; 0.05 for push and push-sphere,
    the paper's slippery world)."""
    horizon: int | None = None
    """the horizon T [steps] (default: the task's; 100 for push, 60 for push-sphere, 80 for push-panda; not
    grasp-panda's)."""
    object: str | None = None
    """push: the DANO to push, FILE.dano or builtin:NAME (default builtin:bunny)."""
    goal: Annotated[str | None, tyro.conf.arg(metavar="X,Y")] = None
    """push: where the object's centre of mass should end, X,Y world frame [m] (it starts at 0 0; default: one
    longest extent along +x, half of one along +y)."""
    pusher: str | None = None
    """push: the pusher, sphere (the default and, for now, the only one for any object)."""
    no_video: bool = False
    """skip the video."""
    quiet: bool = False
    """no progress bars."""

    def __post_init__(self):
        if self.contact_model is not None and self.contact_model not in CONTACT_MODELS:
            raise DanoError(f"unknown --contact-model {self.contact_model!r}; available: {', '.join(CONTACT_MODELS)}")
        self.goal_xy()  # checked now

    def goal_xy(self) -> tuple[float, float] | None:
        """--goal as two numbers [m]. Raises DanoError unless it is two finite numbers X,Y."""
        if self.goal is None:
            return None
        try:
            xy = tuple(float(v) for v in self.goal.split(","))
        except ValueError:
            xy = ()
        if len(xy) != 2 or not np.all(np.isfinite(xy)):
            raise DanoError(f"--goal must be two numbers X,Y [m], got {self.goal!r}")
        return xy


def trajopt_command(config: TrajoptCommandConfig, progress=None) -> tuple[dict, list]:
    """``dano trajopt``: solve the task (:func:`run`), its report made JSON-safe (non-finite
    values as null, listed in ``warnings``), every output written to ``out_dir`` (default
    ``trajopt-<task>/``, :func:`write_outputs`). Returns (report, paths written). Raises
    DanoError before the solve if the video cannot be made here (no OpenGL for MuJoCo, no
    ffmpeg: :func:`~dano.viz.video.check_mujoco_video`)."""
    if not config.no_video:
        check_mujoco_video("video.mp4", "the video (--no-video to leave it out)")
    task, solution, me, rep = run(config.task, progress=progress, model_error=config.model_error,
                                  max_iterations=config.max_iterations, contact_model=config.contact_model,
                                  sliding_friction=config.sliding_friction, horizon=config.horizon,
                                  object=config.object, goal=config.goal_xy(), pusher=config.pusher)
    rep, nonfinite = json_safe(rep)
    if nonfinite:
        rep["warnings"] = rep.get("warnings", []) + [f"not finite (written as null): {', '.join(nonfinite)}"]
    out_dir = config.out_dir or Path(f"trajopt-{task.config.task}")
    paths = write_outputs(task, solution, me, rep, out_dir, video=not config.no_video, progress=progress)
    return rep, paths
