"""A simulation run as ``dano simulate`` does it, as library calls: a typed
:class:`SimulateConfig` (saved beside every output and loadable again), :func:`simulate`
(scene set-up, parameters, rollout) and :func:`write_outputs` (trajectory, video and the
resolved configuration: all published together, or none).

Ten lines of Python do what the command does::

    from dano.sim.run import SimulateConfig, simulate, write_outputs
    run = simulate(SimulateConfig("scene.xml", object=("spot.dano@0,0,0.5",), duration=2.0))
    write_outputs(run, out="spot.npz", video="spot.mp4")
"""

from __future__ import annotations

import dataclasses
import math
import time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated

import jax.numpy as jnp
import numpy as np
import tyro

from .._config import read_table, typed_table
from .._compiled import compile_seconds
from .._files import atomic_path, config_json
from ..contact import CONTACT_MODELS
from ..data import load_asset
from ..errors import DanoError
from ..trajectory import Trajectory, save_trajectory
from ..viz.video import camera_id, check_mujoco_video, write_video
from .rollout import rollout
from .dynamics import State
from .scene import DanoObject, Scene, SimParams
from .scenes import BUILTIN_SCENES, Setup, load_scene, mjcf_setup

DEFAULT_OBJECT = "builtin:bunny@0,0,1"


@dataclass(frozen=True)
class SimulateConfig:
    """What ``dano simulate`` runs, saved as ``<output>.config.json`` and read back by
    ``--config`` (TOML or JSON; keys as the options; paths relative to the file).
    Raises DanoError naming the option for a value out of range."""

    scene: str
    """A built-in scene name (bunny-drop, bunny-slide, sphere-hits-bunny, two-bunnies-sphere,
    panda-push-bunny) or an MJCF path."""
    duration: float | None = None
    """Simulated time [s]; None: the scene's."""
    dt: float | None = None
    """Time step [s]; None: the scene's (an MJCF's ``<option timestep>``, else 0.01)."""
    param: tuple[str, ...] = ()
    """Contact parameters ``name=value`` for every pair or ``PAIR:name=value`` for one
    (e.g. ``sliding_friction=0.3``, ``bunny/ground:impact_spring=5e4``, ``alpha=0.2``)."""
    object: tuple[str, ...] = ()
    """MJCF scenes: DANOs to add, ``FILE.dano`` or ``builtin:NAME``, optionally
    ``@x,y,z`` or ``@x,y,z,qw,qx,qy,qz`` (world frame [m], quaternion wxyz); empty: the bunny at 1 m."""
    fps: float = 30.0
    """Video frame rate [1/s]."""
    contact_model: str = "centroid"
    """DANO contact model of every pair: centroid (the paper's) or per_sample."""
    max_steps: int = 2_000_000
    """Refuse a run of more steps than this (duration / dt) up front."""
    qvel: tuple[str, ...] = ()
    """Initial velocities of DANOs, ``NAME=vx,vy,vz`` or ``NAME=vx,vy,vz,wx,wy,wz``: linear
    velocity, world frame [m/s], then angular velocity, body frame [rad/s] (MuJoCo's free-joint
    qvel); NAME is the DANO's name (its file stem, or the asset's name); others start at rest."""
    camera: str | None = None
    """Video: the name of a camera in the scene's MJCF; None: a free camera following the DANOs."""
    keyframe: str | None = None
    """MJCF scenes: start from this key of the MJCF's ``<keyframe>``, by name or index ("0"; an int
    is read as its index):
    its qpos and qvel for the MJCF's own joints and its ctrl, held for the whole run (time is not
    used); the DANOs keep their ``object`` pose and ``qvel``. None: the MJCF's qpos0, at rest."""

    def __post_init__(self):
        for item in self.qvel:
            parse_velocity(item)
        if self.contact_model not in CONTACT_MODELS:
            raise DanoError(f"unknown --contact-model {self.contact_model!r}; available: {', '.join(CONTACT_MODELS)}")
        for opt, v in (("duration", self.duration), ("dt", self.dt), ("fps", self.fps)):
            if v is not None and not (0 < v < math.inf):
                raise DanoError(f"--{opt} must be a finite positive number, got {v}")
        if self.max_steps < 1:
            raise DanoError(f"--max-steps must be at least 1, got {self.max_steps}")
        if isinstance(self.keyframe, int) and not isinstance(self.keyframe, bool) and self.keyframe >= 0:
            object.__setattr__(self, "keyframe", str(self.keyframe))  # an index, saved as the option reads it
        if self.keyframe is not None and not (isinstance(self.keyframe, str) and self.keyframe.strip()):
            raise DanoError(f"--keyframe {self.keyframe!r}: give a key's name or its index (0 for the first)")

    @classmethod
    def read(cls, path: str | Path) -> SimulateConfig:
        """A saved configuration (TOML or JSON), with paths made absolute against its folder.
        Raises DanoError naming the file and the key."""
        path = Path(path)
        try:
            c = typed_table(read_table(path), cls, "")
        except DanoError as exc:
            raise DanoError(str(exc) if str(path) in str(exc) else f"{path}: {exc}") from exc
        return dataclasses.replace(c, scene=absolute_source(c.scene, path.parent),
                                   object=tuple(absolute_source(o, path.parent) for o in c.object))

    def absolute(self, base: str | Path = ".") -> SimulateConfig:
        """The same configuration with file paths absolute against ``base``."""
        return dataclasses.replace(self, scene=absolute_source(self.scene, Path(base)),
                                   object=tuple(absolute_source(o, Path(base)) for o in self.object))


def absolute_source(text: str, base: Path) -> str:
    """'FILE[@x,y,z...]' with FILE made absolute against ``base`` (builtin: and scene names kept)."""
    src, at, pos = text.partition("@")
    if src.startswith("builtin:") or src in BUILTIN_SCENES:
        return text
    return str((Path(base) / src).resolve()) + at + pos


def parse_object(text: str) -> DanoObject:
    """'FILE.dano[@x,y,z[,qw,qx,qy,qz]]' or 'builtin:NAME[@...]' -> :class:`DanoObject`:
    position [m, world] (default 0, 0, 1) and optionally the orientation (a quaternion
    w x y z, normalised here). Raises DanoError for a malformed pose."""
    src, _, at = text.partition("@")
    pos, quat = (0.0, 0.0, 1.0), (1.0, 0.0, 0.0, 0.0)
    if at:
        try:
            values = np.array([float(v) for v in at.split(",")])
            ok = len(values) in (3, 7) and bool(np.all(np.isfinite(values)))
        except ValueError:
            ok = False
        if not ok:
            raise DanoError(f"--object {text!r}: the pose must be x,y,z or x,y,z,qw,qx,qy,qz (finite numbers)")
        pos = tuple(values[:3])
        if len(values) == 7:
            norm = float(np.linalg.norm(values[3:]))
            if norm < 1e-9:
                raise DanoError(f"--object {text!r}: the quaternion qw,qx,qy,qz must not be zero")
            quat = tuple(values[3:] / norm)
    asset = load_asset(src)
    return DanoObject(asset.name or Path(src).stem, asset, pos, quat)


def parse_velocity(text: str) -> tuple[str, np.ndarray]:
    """'NAME=vx,vy,vz[,wx,wy,wz]' -> (NAME, (6,) qvel of its free joint: linear world [m/s],
    angular body frame [rad/s]). Raises DanoError for a malformed value."""
    name, eq, values = text.partition("=")
    try:
        v = np.array([float(x) for x in values.split(",")]) if eq else np.array([])
        ok = bool(name) and len(v) in (3, 6) and bool(np.all(np.isfinite(v)))
    except ValueError:
        ok = False
    if not ok:
        raise DanoError(f"--qvel {text!r}: expected NAME=vx,vy,vz or NAME=vx,vy,vz,wx,wy,wz (finite numbers: m/s, "
                        "world frame; rad/s, body frame)")
    return name, np.concatenate([v, np.zeros(6 - len(v))])


def with_velocities(scene: Scene, state: State, assignments) -> State:
    """``state`` with each DANO's free-joint velocity set from ``assignments``
    (:func:`parse_velocity` strings). Raises DanoError for an unknown DANO (naming the scene's)."""
    qvel = np.array(state.qvel, dtype=np.float64)
    for item in assignments:
        name, v = parse_velocity(item)
        if name not in scene.dano_names:
            raise DanoError(f"--qvel {item!r}: no DANO named {name!r}; the scene's DANOs: {', '.join(scene.dano_names)}")
        a = scene.dof_adr[scene.dano_names.index(name)]
        qvel[a : a + 6] = v
    return dataclasses.replace(state, qvel=jnp.asarray(qvel, dtype=state.qvel.dtype))


def apply_params(scene: Scene, params: SimParams, assignments) -> SimParams:
    """``params`` with each ``name=value`` / ``PAIR:name=value`` of ``assignments`` set
    (:meth:`Scene.set_param`). Raises DanoError for a malformed assignment."""
    for item in assignments:
        key, eq, value = item.partition("=")
        if not eq:
            raise DanoError(f"--param {item!r}: expected name=value or pair:name=value")
        target, _, name = key.rpartition(":")
        try:
            v = float(value)
        except ValueError:
            raise DanoError(f"--param {item!r}: {value!r} is not a number") from None
        params = scene.set_param(params, name, v, target or None)
    return params


@dataclass(frozen=True)
class SimulationRun:
    """A finished run: the scene set-up, the parameters used, the trajectory, the wall time
    [s] (compilation included), the resolved configuration (every default filled in) and the
    part of the wall time spent tracing, lowering and compiling (loads from the caches
    included) [s]."""

    setup: Setup
    params: SimParams
    trajectory: Trajectory
    wall_time_s: float
    config: SimulateConfig
    compile_time_s: float = 0.0

    def summary(self) -> dict:
        """The run in numbers (JSON-able): scene, steps, dt [s], duration [s], wall_time_s,
        compile_time_s, run_time_s (their difference), and per DANO its mass [kg], final
        centre of mass (world [m]) and final speed [m/s], per contact pair its final
        overlap ψ, failure_substeps: 1, or the substeps each step whose Newton solve failed
        was taken again in where the run diverged or had failed steps with single steps
        (:func:`~dano.sim.rollout`), and failed_steps: how many steps failed (taken again in
        substeps, or kept as they were)."""
        scene, traj = self.setup.scene, self.trajectory
        return {"scene": scene.name, "steps": len(traj.time) - 1, "dt": scene.dt, "duration": float(traj.time[-1]),
                "wall_time_s": self.wall_time_s, "compile_time_s": self.compile_time_s,
                "run_time_s": max(self.wall_time_s - self.compile_time_s, 0.0),
                "objects": {n: {"mass": float(a.mass), "final_center_of_mass": traj.dano_pose(n)[0][-1].tolist(),
                                "final_speed": float(np.linalg.norm(traj.qvel[-1, d : d + 3]))}
                            for n, a, d in zip(scene.dano_names, scene.assets, scene.dof_adr)},
                "final_overlap": {p: float(x) for p, x in zip(scene.pair_names, traj.psi[-1])},
                "failure_substeps": int(traj.metadata.get("failure_substeps", 1)),
                "failed_steps": int(traj.metadata.get("failed_steps", 0))}


def setup_for(config: SimulateConfig) -> Setup:
    """The scene of ``config``: a built-in scene, or the MJCF with its DANOs placed.
    Raises DanoError for an unknown scene or objects given to a built-in one."""
    if config.scene in BUILTIN_SCENES:
        for option, value in (("--object", config.object), ("--keyframe", config.keyframe)):
            if value:
                raise DanoError(f"{option} applies to MJCF scenes, not to built-in ones")
        return load_scene(config.scene, config.dt, contact_model=config.contact_model)
    path = Path(config.scene)
    if path.suffix.lower() != ".xml" and not path.exists():
        raise DanoError(f"unknown scene {config.scene!r}; built-in scenes: {', '.join(BUILTIN_SCENES)} "
                        "(or an MJCF path)")
    objs = [parse_object(o) for o in (config.object or (DEFAULT_OBJECT,))]
    return mjcf_setup(path, objs, dt=config.dt, contact_model=config.contact_model,  # dt None: the MJCF's
                      keyframe=config.keyframe)


def simulate(config: SimulateConfig, progress=None) -> SimulationRun:
    """Set up ``config``'s scene, apply its parameters and roll it out (one compiled scan).
    progress: optional callback ``(done, total, label)``. Raises DanoError for a run of more
    than ``max_steps`` steps or less than one, and :class:`~dano.sim.SimulationDiverged` when
    the state leaves the finite range (nothing returned)."""
    setup = setup_for(config)
    params = apply_params(setup.scene, setup.params, config.param)
    state0 = with_velocities(setup.scene, setup.state0, config.qvel)
    if config.camera is not None:
        camera_id(setup.scene.mj_model, config.camera)  # before the run: an unknown name is refused now
    dt = setup.scene.dt
    T = int(round((config.duration if config.duration is not None else setup.duration) / dt))
    if T < 1:
        raise DanoError(f"--duration must cover at least one step of {dt:g} s")
    if T > config.max_steps:
        raise DanoError(f"--duration / --dt: {T} steps of {dt:g} s is more than --max-steps {config.max_steps} "
                        f"(the trajectory alone would take {T * (setup.scene.nq + setup.scene.nv) * 8 / 1e9:.2g} GB)")
    controls = setup.controls(np.arange(T) * dt) if setup.controls else None
    t0, started = time.perf_counter(), time.time()
    traj = rollout(setup.scene, state0, controls, params, T, progress=progress)
    resolved = dataclasses.replace(config.absolute(), duration=T * dt, dt=dt)
    return SimulationRun(setup, params, traj, time.perf_counter() - t0, resolved, compile_seconds(started))


def check_video_path(video: str | Path | None) -> None:
    """Raises DanoError unless ``video`` is None or a video MuJoCo can render and write here
    (:func:`~dano.viz.video.check_mujoco_video`); checked before a run."""
    if video is not None:
        check_mujoco_video(video, f"--video {video}")


@dataclass(frozen=True)
class SimulateCommandConfig:
    """Simulate a built-in scene or an MJCF file with DANOs and write the trajectory and a video."""

    scene: Annotated[str | None, tyro.conf.Positional, tyro.conf.arg(metavar="SCENE")] = None
    """built-in name (bunny-drop, bunny-slide, sphere-hits-bunny, two-bunnies-sphere, panda-push-bunny) or an
    MJCF path (optional with --config)."""
    config: Path | None = None
    """a configuration (TOML or JSON, e.g. the <out>.config.json a run saved) whose values are used for every
    option not given on the command line; the run then repeats that one."""
    duration: float | None = None
    """simulated time [s] (default: the scene's)."""
    dt: float | None = None
    """time step [s] (default: the scene's; for an MJCF, its <option timestep>, else 0.01)."""
    param: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VALUE")] = ()
    """contact parameters name=value for all pairs, or PAIR:name=value for one pair (e.g. sliding_friction=0.3,
    bunny/ground:impact_spring=5e4, alpha=0.2)."""
    object: Annotated[tuple[str, ...], tyro.conf.arg(metavar="FILE@X,Y,Z")] = ()
    """MJCF scenes: DANOs to add, FILE.dano or builtin:NAME, optionally @x,y,z or @x,y,z,qw,qx,qy,qz (position
    [m] and orientation, world frame) (default: builtin:bunny@0,0,1)."""
    out: Annotated[Path | None, tyro.conf.arg(aliases=("-o",))] = None
    """trajectory .npz (time, qpos, qvel, psi, names)."""
    video: Path | None = None
    """.mp4 (or .gif) video, rendered headless with MuJoCo."""
    fps: float | None = None
    """video frame rate (default 30)."""
    contact_model: str | None = None
    """DANO contact model of every pair: centroid (the paper's, default) or per_sample."""
    max_steps: int | None = None
    """refuse a run of more steps than this (duration / dt) up front (default 2000000)."""
    qvel: Annotated[tuple[str, ...], tyro.conf.arg(metavar="NAME=VX,VY,VZ[,WX,WY,WZ]")] = ()
    """initial velocities of DANOs: linear, world frame [m/s], then angular, body frame [rad/s]
    (e.g. bunny=1,0,0 or bunny=1,0,0,0,0,5); other bodies start at rest."""
    camera: str | None = None
    """video: a camera of the MJCF, by name (default: a free camera following the DANOs)."""
    keyframe: Annotated[str | None, tyro.conf.arg(metavar="NAME|INDEX")] = None
    """MJCF scenes: start from this key of the MJCF's <keyframe> (name, or index from 0): its qpos, qvel and
    ctrl for the MJCF's own joints and actuators (ctrl held for the run); DANOs keep --object's pose and --qvel
    (default: the MJCF's reference pose qpos0, at rest)."""
    quiet: bool = False
    """no progress bars."""
    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object (SimulationRun.summary: scene, steps, dt, duration, wall_time_s, compile_time_s,
    run_time_s, objects (mass, final_center_of_mass, final_speed), final_overlap) and the files written, under
    "files", instead of the table."""

    def __post_init__(self):
        check_video_path(self.video)
        if self.scene is None and self.config is None:
            raise DanoError("give a SCENE (or --config)")

    def resolved(self) -> SimulateConfig:
        """The :class:`SimulateConfig` to run: the options given, the rest from ``config``
        (if any) or the defaults. Raises DanoError for a value out of range."""
        given = {"duration": self.duration, "dt": self.dt, "param": self.param, "object": self.object,
                 "fps": self.fps, "contact_model": self.contact_model, "max_steps": self.max_steps,
                 "qvel": self.qvel, "camera": self.camera, "keyframe": self.keyframe}
        given = {k: v for k, v in given.items() if v not in (None, ())}
        if self.config is not None:
            saved = SimulateConfig.read(self.config)
            return dataclasses.replace(saved, scene=self.scene or saved.scene, **given)
        return SimulateConfig(self.scene, **given)



def write_outputs(run: SimulationRun, out: str | Path | None = None, video: str | Path | None = None,
                  progress=None) -> list[Path]:
    """Write the trajectory ``out`` (.npz: time, qpos, qvel, psi, names), the ``video`` (.mp4
    or .gif, rendered headless with MuJoCo at the config's fps) and the resolved
    configuration ``<first output>.config.json``: all published together at the end, or none.
    Returns the paths written. Raises DanoError for a video suffix other than .mp4/.gif."""
    out, video = (None if p is None else Path(p) for p in (out, video))
    check_video_path(video)
    first = out if out is not None else video
    saved = first.with_name(f"{first.stem}.config.json") if first is not None else None
    with ExitStack() as stack:
        if saved is not None:
            stack.enter_context(atomic_path(saved)).write_text(config_json(dataclasses.asdict(run.config)))
        if video is not None:
            write_video(run.setup.scene, run.trajectory, stack.enter_context(atomic_path(video)), fps=run.config.fps,
                        progress=progress, camera=run.config.camera)
        if out is not None:
            save_trajectory(run.trajectory, stack.enter_context(atomic_path(out)))
    return [p for p in (out, video, saved) if p is not None]
