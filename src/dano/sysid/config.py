"""Identification runs from a TOML problem file (the built-in examples are experiments:
:mod:`dano.experiments`). A TOML file describes a user problem::

    [scene]
    mjcf = "table.xml"            # optional; default: empty world with a ground plane
    dt = 0.01                     # simulation step [s] = frame interval / substeps
    contact_model = "centroid"    # or "per_sample"
    # friction_steepness = 100    # s [s/m] of the smoothed Coulomb friction (default 100; the paper's code: 30)
    [[scene.object]]
    name = "soap"
    asset = "soap.dano"           # or "builtin:bluesoap"
    pos = [0.0, 0.0, 0.4]
    quat = [1.0, 0.0, 0.0, 0.0]

    [contact]                     # fixed contact parameters (all pairs); the rest: paper defaults, except
    sliding_drag = 0.0            # sliding_drag, held at 0 when sliding_friction is identified

    [[trajectory]]
    file = "run1.csv"             # CSV columns t,x,y,z,qw,qx,qy,qz (header line), a .npz with arrays
                                  # time (T,), poses (T, 7) [, velocities (T, 6)], or a dano trajectory .npz
    object = "soap"               # which DANO the CSV tracks
    velocities = false            # true: start every window from measured velocities: CSV columns
                                  # vx,vy,vz (world, m/s), wx,wy,wz (body, rad/s), or the .npz's qvel

    [[parameter]]
    name = "sliding_friction"     # a contact parameter, "alpha", or com_offset_x|y|z [m],
                                  # second_moment_scale_x|y|z, principal_axes_x|y|z [rad]
    initial = 0.3
    lower = 0.0
    upper = 2.0
    # target = "soap/ground"      # one pair (or DANO for alpha); default all

    [options]
    substeps = 1
    fit_velocity = "xy"           # nuisance initial velocity axes (default "auto")
    fit_angular_velocity = ""     # nuisance initial angular velocity axes (body frame)
    fit_position = ""             # nuisance initial position axes (world frame), e.g. "xy" for noisy starts
    fit_rotation = ""             # nuisance initial rotation-vector axes (world frame), e.g. "z" (heading)
    start_prior = true            # each fitted start offset also weighed by what the frames say of it
    start_velocity = "auto"       # "first frames", "next frames" (a first frame that is off), "auto"
    window = 0                    # >0: multiple shooting windows of this many frames
    auto_windows = false          # true: a window from just before each observed impact instead
    horizons = []                 # continuation, e.g. [0.4]
    scan = 15                     # global start: points per parameter of a scan of the bounds; left out:
                                  # 15 for one parameter, 8 x 8 for two, 64 Sobol points beyond; 0: off
    starts = 2                    # local solves from the scan's points, one per basin (the guess among them)
    profile_points = 32           # verification and interval: a profile through the estimate along each
                                  # parameter (left out: 32 for one or two parameters, 16 beyond; 0: off)
    level = 0.95                  # the interval's level
    fit_ground = false            # fit the ground plane's height (nuisance "ground_height" [m])
    fit_tilt = false              # with fit_ground: also its tilt ("ground_tilt_x", "ground_tilt_y" [rad])
    noise_rms = 0.002             # optional: rms residual of the noise alone; warn when the fit is worse
    bootstrap = 0                 # >0: resample whole trajectories this many times and refit (t-interval)
    position_weights = [1.0, 1.0, 1.0]  # [1/m^2]
    rotation_weight = 1.0         # [1/rad^2]; left out: rotations weighed by the object's size (a rotation
                                  # of theta rad counts as theta x sqrt(tr J / 3m) metres)
    jacobian = "ad"

Relative paths are resolved against the file's folder. The file is read into typed
dataclasses (:func:`read_config`): unknown keys, wrong types and out-of-range values are
refused naming the key; at least one ``[[parameter]]`` is required. Everything resolved
(defaults included) is returned so that it can be saved next to the results. Every key, its
type, default and meaning: docs/config-reference.md (generated from the field docstrings).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .. import sharding
from .._config import read_table, typed_table
from .._files import read_npz
from ..asset import load
from ..data import load_asset, load_builtin
from ..errors import DanoError, FileFormatError
from ..sim.scene import DEFAULT_DT, stated_timestep
from ..sim.scene import DanoObject, compose, contact_model_or_error
from ..trajectory import load_trajectory
from .problem import (MIN_RUN_FRAMES, START_VELOCITIES, FitParameter, Observation, SysIdProblem, Weights,
                      identification_params, is_jittered)
from .outputs import estimates_report
from .solve import identify



#: optional CSV columns of measured velocities: linear (world) [m/s], angular (body) [rad/s]
VELOCITY_COLUMNS = ("vx", "vy", "vz", "wx", "wy", "wz")


def _observation(path: Path, time, poses: dict, vel: dict, left_out=(), why: str = "") -> Observation:
    """The :class:`~dano.sysid.Observation` of a file's ``time`` (T,), ``poses`` {name: (T, 7)}
    and ``vel`` {name: (T, 6)} without the frames ``left_out`` (indices), which are then
    missing frames like dropped ones (:meth:`~dano.sysid.Observation.runs`), its frame interval
    kept from all the frames. Raises DanoError naming the file and ``why`` they were left out
    where no run of :data:`MIN_RUN_FRAMES` frames is left."""
    time = np.asarray(time, dtype=np.float64)
    keep = np.ones(len(time), dtype=bool)
    keep[np.asarray(left_out, dtype=int)] = False
    if keep.all() or time.ndim != 1 or len(time) < 2:
        return Observation(time=time, poses=poses, velocities=vel, name=path.name)
    step = float(np.min(np.diff(time)))  # (the interval, whichever frames are left out)
    if is_jittered(Observation(time=time)):  # (then the simulation's, dt x substeps: SysIdProblem)
        step = None
    runs = Observation(time=time[keep], frame_interval=step).runs() if keep.sum() > 1 else ()
    if max((n for _, n in runs), default=0) < MIN_RUN_FRAMES:
        raise DanoError(f"{path}: {len(time) - keep.sum()} of its {len(time)} frames {why}, and without them no "
                        f"{MIN_RUN_FRAMES} consecutive frames are left")
    return Observation(time=time[keep], poses={k: np.asarray(v)[keep] for k, v in poses.items()},
                       velocities={k: np.asarray(v)[keep] for k, v in vel.items()}, name=path.name,
                       frame_interval=step)


def _lost_rows(poses: np.ndarray) -> np.ndarray:
    """Indices of the rows (T, 7) whose seven pose values are all missing (empty or NaN: a frame
    the tracker lost); a row missing only some stays (and is refused)."""
    return np.flatnonzero(~np.any(np.isfinite(poses), axis=1)) if poses.ndim == 2 else np.zeros(0, dtype=int)


def _read_observation(path: Path, obj: str | None, scene, velocities: bool = False,
                      skip_poor_frames: bool = True) -> Observation:
    """A ``[[trajectory]]`` file as an :class:`~dano.sysid.Observation`: a CSV (t, x, y, z,
    qw, qx, qy, qz [, vx, vy, vz, wx, wy, wz]), an NPZ of time and poses [and velocities], or
    a dano trajectory. CSV and NPZ rows whose pose is all empty or NaN are frames the tracker
    lost: left out, as missing frames; so are the frames a dano track trajectory lists as
    poor (metadata ``poor_frames``) where ``skip_poor_frames``. Raises FileFormatError or
    DanoError naming the file."""
    if not path.is_file():
        raise FileFormatError(f"{path}: no such trajectory file")
    if path.suffix.lower() == ".csv":
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("error")  # e.g. "empty input file": an error here, not a warning
                data = np.genfromtxt(path, delimiter=",", names=True)
        except Exception as exc:
            lines = [x.strip() for x in str(exc).splitlines() if x.strip()]
            more = f" and {len(lines) - 2} more" if len(lines) > 2 else ""
            raise FileFormatError(f"{path}: cannot read CSV ({' '.join(lines[:2])}{more})") from exc
        cols = ("t", "x", "y", "z", "qw", "qx", "qy", "qz")
        if data.dtype.names is None or any(c not in data.dtype.names for c in cols):
            raise FileFormatError(f"{path}: CSV needs a header with columns {', '.join(cols)}")
        if obj is None:
            raise DanoError(f"{path}: say which object the CSV tracks (object = \"name\")")
        poses = np.stack([data[c] for c in cols[1:]], axis=1)
        vel = {}
        if velocities:
            missing = [c for c in VELOCITY_COLUMNS if c not in data.dtype.names]
            if missing:
                raise FileFormatError(f"{path}: velocities = true needs the columns {', '.join(VELOCITY_COLUMNS)}; "
                                      f"missing {', '.join(missing)}")
            vel = {obj: np.stack([data[c] for c in VELOCITY_COLUMNS], axis=1)}
        return _observation(path, data["t"], {obj: poses}, vel, _lost_rows(poses), "have no pose")

    arrays = read_npz(path, (), "trajectory")
    if "poses" in arrays:  # the plain layout: time (T,), poses (T, 7), optional velocities (T, 6)
        if obj is None:
            raise DanoError(f"{path}: say which object the poses track (object = \"name\")")
        if "time" not in arrays:
            raise FileFormatError(f"{path}: a .npz of poses needs the arrays time (T,) and poses (T, 7)")
        vel = {}
        if velocities:
            if "velocities" not in arrays:
                raise FileFormatError(f"{path}: velocities = true needs an array velocities (T, 6)")
            vel = {obj: np.asarray(arrays["velocities"], dtype=np.float64)}
        poses = np.asarray(arrays["poses"], dtype=np.float64)
        time = np.asarray(arrays["time"], dtype=np.float64)
        fits = poses.ndim == 2 and poses.shape[1] == 7 and time.shape == (len(poses),)  # (else refused, shape named)
        return _observation(path, time, {obj: poses}, vel, _lost_rows(poses) if fits else (), "have no pose")
    traj = load_trajectory(path)
    names = [obj] if obj else list(traj.dano_names)
    poses, vel = {}, {}
    for n in names:
        if n not in traj.dano_names:
            hint = (f"; set object = {json.dumps(traj.dano_names[0])} in its [[trajectory]] and name the scene's "
                    "object alike" if len(traj.dano_names) == 1 else "")
            raise DanoError(f"{path}: no DANO {n!r} in the trajectory (it has {list(traj.dano_names)}){hint}")
        poses[n] = np.concatenate(traj.dano_pose(n), axis=1)
        if velocities:  # the file's qvel at the DANO's free joint (simulated, or central differences of tracking)
            adr = traj.dof_adr[traj.dano_names.index(n)]
            vel[n] = np.asarray(traj.qvel)[:, adr : adr + 6]
    poor = np.asarray(traj.metadata.get("poor_frames", []) if skip_poor_frames else [], dtype=int)
    poor = poor[(poor >= 0) & (poor < len(traj.time))]
    return _observation(path, traj.time, poses, vel, poor, "are flagged poor by the tracker (check overlay.mp4, or "
                        "keep them: [[trajectory]] skip_poor_frames = false)")


# ------------------------------------------------------------------ typed schema
# Each table of the TOML file is read into a frozen dataclass; unknown keys, missing keys
# and wrong types are refused naming the key ("[options].substeps: ..."), values out of
# range by each table's __post_init__ (the whole file's cross-table checks: SysIdConfig's).


def _axes_ok(axes: str) -> bool:
    return not (set(axes) - set("xyz")) and len(set(axes)) == len(axes)


@dataclass(frozen=True)
class ObjectConfig:
    """``[[scene.object]]``: one DANO of the scene."""

    name: str
    """The object's name (a body of the scene; ``[[trajectory]].object`` and parameter targets name it)."""
    asset: str
    """Its DANO: a ``.dano`` file (relative to the TOML file's folder) or ``builtin:NAME`` (e.g.
    ``builtin:bluesoap``)."""
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    """Initial position of its body frame (the centre of mass) [m], world frame, (3,)."""
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    """Initial orientation, a unit quaternion (w, x, y, z), world frame, (4,)."""


@dataclass(frozen=True)
class SceneConfig:
    """``[scene]``: the simulated world."""

    dt: float
    """Simulation step [s] = the observed frame interval / ``[options].substeps``; > 0."""
    object: tuple[ObjectConfig, ...]
    """The DANOs (at least one), each a ``[[scene.object]]`` table."""
    mjcf: str | None = None
    """An MJCF world (relative to the TOML file's folder) the objects are added to; left out: an empty world with a
    ground plane."""
    contact_model: str = "centroid"
    """DANO contact model of every pair: ``centroid`` (the paper's) or ``per_sample``."""
    friction_steepness: float | None = None
    """Steepness s [s/m] of every pair's smoothed Coulomb direction, −(2/π)·atan(s|v|)·v/(10⁻³ + |v|)
    (docs/simulation.md); > 0. Left out: dano's default, 100 (the paper's code: 30). 300 fitted hard-Coulomb
    slides from plain MuJoCo a little better (docs/sysid.md) but is less robust with stiff contacts at large
    steps."""

    def __post_init__(self):
        if not (0 < self.dt < np.inf):
            raise DanoError(f"[scene].dt: must be a finite positive step [s], got {self.dt}")
        if self.friction_steepness is not None and not (0 < self.friction_steepness < np.inf):
            raise DanoError(f"[scene].friction_steepness: must be a finite positive steepness [s/m], "
                            f"got {self.friction_steepness}")
        if not self.object:
            raise DanoError("[[scene.object]]: at least one object is needed")


@dataclass(frozen=True)
class TrajectoryConfig:
    """``[[trajectory]]``: one observed trajectory."""

    file: str
    """The observation (relative to the TOML file's folder): a CSV with a header line and columns
    ``t,x,y,z,qw,qx,qy,qz`` (time [s], body position [m] and wxyz quaternion, world frame), a ``.npz`` with arrays
    ``time`` (T,), ``poses`` (T, 7) [, ``velocities`` (T, 6)], or a dano trajectory ``.npz``. Frames at one frame
    rate; frames may be missing (dropped rows, or CSV/``.npz`` rows whose pose is all empty or NaN: lost by a
    tracker), each run of consecutive frames then rolled out from its own first frame; time stamps may jitter by up
    to a quarter of the frame interval (dt x substeps), each frame then compared with the simulation at its own
    time."""
    object: str | None = None
    """Which ``[[scene.object]]`` the CSV or plain ``.npz`` tracks; left out for a dano trajectory: every object
    it holds."""
    velocities: bool = False
    """Start every window from measured velocities: CSV columns ``vx,vy,vz`` (world [m/s]) and ``wx,wy,wz`` (body
    [rad/s]), the ``.npz``'s ``velocities`` (T, 6) or the dano trajectory's qvel."""
    skip_poor_frames: bool = True
    """Leave out the frames a tracker flagged poor (``dano track``'s trajectory lists them: silhouette IoU below its
    cut, e.g. where something hides the object), as missing frames; false: keep their poses as tracked."""


@dataclass(frozen=True)
class ParameterConfig:
    """``[[parameter]]``: one parameter to identify, its initial guess and bounds."""

    name: str
    """A contact parameter (``sliding_friction``, ``impact_spring``, ...: Table I), ``alpha``, ``com_offset_x|y|z``
    [m], ``second_moment_scale_x|y|z`` [-] or ``principal_axes_x|y|z`` [rad]."""
    initial: float
    """Initial guess, within [lower, upper] (the parameter's unit)."""
    lower: float = 0.0
    """Lower bound; < 0 only for ``com_offset_*`` and ``principal_axes_*``."""
    upper: float | None = None
    """Upper bound; left out: none."""
    target: str | None = None
    """One contact pair (``"soap/ground"``) or, for ``alpha`` and the dynamics parameters, one object; left
    out: every pair (object)."""

    def __post_init__(self):
        where = f"[[parameter]] ({self.name}{', ' + self.target if self.target else ''})"
        upper = np.inf if self.upper is None else self.upper
        if not (np.isfinite(self.initial) and np.isfinite(self.lower)) or np.isnan(upper):
            raise DanoError(f"{where}: initial and lower must be finite, upper finite, inf or left out")
        signed = self.name.startswith(("com_offset_", "principal_axes_"))  # offsets and rotations may be negative
        if self.lower < 0 and not signed:
            raise DanoError(f"{where}: lower bound {self.lower} is negative; contact parameters, alpha and second "
                            "moment scales are >= 0")
        if self.lower > upper:
            raise DanoError(f"{where}: lower bound {self.lower} is above upper bound {self.upper}")
        if not self.lower <= self.initial <= upper:
            raise DanoError(f"{where}: initial {self.initial} must lie within [lower, upper] = "
                            f"[{self.lower}, {self.upper}]")


@dataclass(frozen=True)
class OptionsConfig:
    """``[options]``: how the problem is posed and solved."""

    substeps: int = 1
    """Simulation steps per observed frame interval; >= 1."""
    fit_velocity: str = "auto"
    """Nuisance initial linear velocity axes (world frame) fitted per trajectory (window), e.g. ``"xy"``; ``""``:
    none; ``"auto"``: the weighed axes where finite differences of noisy frames make the start velocities uncertain
    by more than 5 % of their typical speed, or the first frames disagree that much with the frames after them (said
    in the result's notes), else none."""
    fit_angular_velocity: str = ""
    """Nuisance initial angular velocity axes (body frame), e.g. ``"z"``."""
    fit_position: str = ""
    """Nuisance initial position axes (world frame), e.g. ``"xy"`` for noisy starts."""
    fit_rotation: str = ""
    """Nuisance initial rotation-vector axes (world frame), e.g. ``"z"`` (the heading)."""
    start_prior: bool = True
    """Each fitted start offset (the ``fit_*`` axes above) also gets one residual row for what the observed frames
    say of it: the start frame's error for a pose offset, the finite-difference velocity's for a velocity offset,
    in the frames' own units. It holds the offsets the frames leave free (a resting object's velocity into the
    floor) near the frames' value; a moving start's velocity row weighs 0.02–0.04 % of a 10-interval window's frames
    (one to many simulation steps per frame), a pose offset's row one frame. Velocities that are given (``velocities``, rest frames) get none; ``false``: plain least
    squares."""
    start_velocity: str = "auto"
    """Where each rollout's start comes from when no velocity is measured or given: ``"first frames"``, the
    first frame's pose and finite differences of the first three frames; ``"next frames"``, at a recording's first
    frame (and the first after missing ones), the parabola through the four frames after it (position and velocity:
    for a first frame that is off); ``"auto"``: ``"next frames"`` where the first three frames' velocities disagree
    with it by more than 5 % of the typical speed and more than the noise explains (from 5 to 15 %, only where the
    second frame's disagree 1.5 times less: the first frame stands out) (said in the result's notes), else
    ``"first frames"``; where it took the next frames and the identification's scan fits better started from the
    first frames (a right first frame and a contact that hops after it), the identification starts from the
    first frames and says so."""
    window: int = 0
    """> 0: multiple shooting, windows of this many frame intervals (>= 2); 0: one shot per trajectory."""
    auto_windows: bool = False
    """A window from just before each observed impact instead (not with ``window``)."""
    horizons: tuple[float, ...] = ()
    """Continuation: first fit these fractions of each trajectory, in (0, 1), e.g. ``[0.4]``."""
    position_weights: tuple[float, float, float] = (1.0, 1.0, 1.0)
    """Weights of the x, y, z position residuals [1/m²], (3,), >= 0."""
    rotation_weight: float | None = None
    """Weight of the rotation residual [1/rad²], >= 0; left out: rotations weighed by the object's size (θ rad
    counts as θ·√(tr J / 3m) metres)."""
    jacobian: str = "ad"
    """Residual Jacobian: ``ad`` (forward-mode automatic differentiation) or ``fd`` (finite differences)."""
    scan: int | None = None
    """Global start: points per parameter of a scan of the bounds, 2 to 64; 0: off; left out: 15 for one
    parameter, 8 × 8 for two, 64 Sobol points beyond."""
    starts: int = 2
    """Local solves from the scan's points (the initial guess among them), at most one per basin the scan
    resolves, lowest cost first, 1 to 16."""
    profile_points: int | None = None
    """Points of a profile through the estimate along each parameter (verification and interval), 8 to 256; 0:
    off; left out: 32 for one or two parameters, 16 beyond."""
    level: float = 0.95
    """The interval's confidence level, in (0, 1)."""
    fit_ground: bool = False
    """Fit the ground plane's height (nuisance ``ground_height`` [m])."""
    fit_tilt: bool = False
    """With ``fit_ground``: also its tilt (``ground_tilt_x``, ``ground_tilt_y`` [rad])."""
    noise_rms: float | None = None
    """RMS residual of the measurement noise alone [m], > 0: warn when the fit is worse; left out: no check."""
    bootstrap: int = 0
    """> 0: resample whole trajectories this many times (2 to 10,000; needs two or more ``[[trajectory]]``) and
    refit, for a t-interval (estimate ∓ t·std of the refits; their percentiles beside it)."""

    def __post_init__(self):
        if self.substeps < 1:
            raise DanoError(f"[options].substeps: must be at least 1, got {self.substeps}")
        if self.window < 0 or self.window == 1:
            raise DanoError(f"[options].window: must be 0 (no windows) or at least 2 frame intervals, "
                            f"got {self.window}")
        for key in ("fit_velocity", "fit_angular_velocity", "fit_position", "fit_rotation"):
            if not (_axes_ok(getattr(self, key)) or key == "fit_velocity" and self.fit_velocity == "auto"):
                raise DanoError(f"[options].{key}: must be made of the letters x, y, z, each at most once, "
                                f"got {getattr(self, key)!r}")
        if self.start_velocity not in START_VELOCITIES:
            raise DanoError(f"[options].start_velocity: one of {', '.join(map(repr, START_VELOCITIES))}, "
                            f"got {self.start_velocity!r}")
        if self.fit_tilt and not self.fit_ground:
            raise DanoError("[options].fit_tilt: the ground's tilt is fitted with its height: "
                            "set fit_ground = true too")
        if self.auto_windows and self.window:
            raise DanoError("[options]: give window (a fixed length) or auto_windows = true, not both")
        if any(not 0 < h < 1 for h in self.horizons):
            raise DanoError(f"[options].horizons: fractions of the trajectory in (0, 1), got {list(self.horizons)}")
        if self.scan is not None and self.scan != 0 and not 2 <= self.scan <= 64:
            raise DanoError(f"[options].scan: 0 (no global scan) or 2 to 64 points per parameter, got {self.scan}")
        if not 1 <= self.starts <= 16:
            raise DanoError(f"[options].starts: 1 to 16 local starts, got {self.starts}")
        if self.profile_points is not None and self.profile_points != 0 and not 8 <= self.profile_points <= 256:
            raise DanoError(f"[options].profile_points: 0 (off) or 8 to 256 points, got {self.profile_points}")
        if not 0 < self.level < 1:
            raise DanoError(f"[options].level: the interval's level, in (0, 1), got {self.level}")
        if self.noise_rms is not None and not 0 < self.noise_rms < np.inf:
            raise DanoError(f"[options].noise_rms: a positive rms residual, got {self.noise_rms}")
        if self.bootstrap != 0 and not 2 <= self.bootstrap <= 10_000:
            raise DanoError(f"[options].bootstrap: 0 or 2 to 10000 resamples, and at least two [[trajectory]] to "
                            f"resample (got {self.bootstrap})")
        if self.jacobian not in ("ad", "fd"):
            raise DanoError(f"[options].jacobian: 'ad' or 'fd', got {self.jacobian!r}")
        weights = (*self.position_weights, 0.0 if self.rotation_weight is None else self.rotation_weight)
        if not all(0 <= w < np.inf for w in weights):
            raise DanoError("[options]: weights must be finite and non-negative")


@dataclass(frozen=True)
class SysIdConfig:
    """A ``dano sysid`` problem file (TOML, or the ``config.json`` a run saves)."""

    scene: SceneConfig
    """The simulated world and its objects."""
    trajectory: tuple[TrajectoryConfig, ...] = ()
    """The observed trajectories (at least one)."""
    parameter: tuple[ParameterConfig, ...] = ()
    """The parameters to identify (at least one)."""
    contact: dict[str, float] = field(default_factory=dict)
    """Fixed contact parameters of every pair (``name = value``, Table I's names); the rest keep the paper's
    defaults, except ``sliding_drag``, held at 0 when ``sliding_friction`` is identified."""
    options: OptionsConfig = OptionsConfig()
    """How the problem is posed and solved."""

    def __post_init__(self):
        if not self.trajectory:
            raise DanoError("[[trajectory]]: at least one trajectory is needed")
        if not self.parameter:
            raise DanoError("[[parameter]]: at least one parameter to identify is needed")
        if self.options.bootstrap != 0 and len(self.trajectory) < 2:
            raise DanoError(f"[options].bootstrap: 0 or 2 to 10000 resamples, and at least two [[trajectory]] to "
                            f"resample (got {self.options.bootstrap} with {len(self.trajectory)})")


def read_config(path: str | Path) -> SysIdConfig:
    """Read and check a sysid configuration (TOML, or the JSON that ``dano sysid`` saves as
    ``config.json``). Raises FileFormatError naming the file and the key."""
    path = Path(path)
    raw = read_table(path)
    try:
        cfg = typed_table(raw, SysIdConfig, "")
    except DanoError as exc:
        raise FileFormatError(f"{path}: {exc}") from exc
    return cfg


def _absolute(cfg: SysIdConfig, base: Path) -> SysIdConfig:
    """The configuration with file paths made absolute, loadable from any folder."""
    def where(p: str) -> str:
        return p if p.startswith("builtin:") else str((base / p).resolve())

    return dataclasses.replace(
        cfg,
        scene=dataclasses.replace(cfg.scene, mjcf=None if cfg.scene.mjcf is None else where(cfg.scene.mjcf),
                                  object=tuple(dataclasses.replace(o, asset=where(o.asset)) for o in cfg.scene.object)),
        trajectory=tuple(dataclasses.replace(t, file=where(t.file)) for t in cfg.trajectory),
    )


def problem_from_toml(path: str | Path) -> tuple[SysIdProblem, dict, dict]:
    """Build the problem described by a TOML file; returns (problem, solver options,
    resolved configuration: every key with its value or default). Raises FileFormatError /
    DanoError naming the file."""
    path = Path(path)
    cfg = read_config(path)
    base = path.parent
    sc, opt = cfg.scene, cfg.options
    try:
        objects = []
        for o in sc.object:
            asset = load_builtin(o.asset.split(":", 1)[1]) if o.asset.startswith("builtin:") else load(base / o.asset)
            objects.append(DanoObject(o.name, asset, o.pos, o.quat))
        mjcf = base / sc.mjcf if sc.mjcf is not None else None
        scene = compose(objects, mjcf, dt=sc.dt, ground=None if mjcf else True, name=path.stem,
                        contact_model=contact_model_or_error(sc.contact_model, sc.friction_steepness))
        # each process of a multi-process run reads its share of the files (dano.sharding)
        obs = sharding.load_shares(cfg.trajectory,
                                   lambda t: _read_observation(base / t.file, t.object, scene, t.velocities,
                                                               t.skip_poor_frames))
        params = [FitParameter(p.name, p.initial, p.lower, np.inf if p.upper is None else p.upper, p.target)
                  for p in cfg.parameter]
        base_params, notes = identification_params(scene, params, cfg.contact)
        weights = Weights(opt.position_weights, opt.rotation_weight)
        problem = SysIdProblem(scene, obs, params, weights, base_params=base_params, substeps=opt.substeps,
                               fit_velocity=opt.fit_velocity, fit_angular_velocity=opt.fit_angular_velocity,
                               fit_position=opt.fit_position, fit_rotation=opt.fit_rotation,
                               start_prior=opt.start_prior, start_velocity=opt.start_velocity,
                               window="auto" if opt.auto_windows else (opt.window or None),
                               fit_ground=opt.fit_ground, fit_tilt=opt.fit_tilt, notes=notes)
    except TypeError as exc:  # e.g. an unknown [contact] parameter name
        raise DanoError(f"{path}: {exc}") from exc
    except DanoError as exc:
        raise DanoError(exc.args[0] if str(path) in str(exc) else f"{path}: {exc}") from exc
    solver = {"jacobian": opt.jacobian, "horizons": opt.horizons, "scan": opt.scan, "starts": opt.starts,
              "noise_rms": opt.noise_rms, "bootstrap_samples": opt.bootstrap, "profile_points": opt.profile_points,
              "level": opt.level}
    return problem, solver, dataclasses.asdict(_absolute(cfg, base))


def solver_options(solver: dict) -> dict:
    """The keyword arguments of :func:`~dano.sysid.identify` from a resolved solver table
    (``jacobian``, ``horizons`` and optionally ``scan``, ``starts``, ``max_iterations``,
    ``noise_rms``, ``bootstrap_samples``, ``profile_points``, ``level``)."""
    return {"jacobian": solver["jacobian"], "horizons": solver["horizons"], "scan": solver.get("scan"),
            "starts": solver.get("starts", 2), "max_iterations": solver.get("max_iterations"),
            "noise_rms": solver.get("noise_rms"), "bootstrap_samples": solver.get("bootstrap_samples", 0),
            "profile_points": solver.get("profile_points"), "level": solver.get("level", 0.95)}


def run(config: str | Path, *, jacobian: str | None = None) -> tuple[SysIdProblem, object, dict]:
    """Run an identification from a TOML problem file or the ``config.json`` an earlier run
    of one saved (which runs the same problem again). Built-in examples (``soap``,
    ``bunny-pushes``, ...) are experiments: :func:`dano.experiments.run_sysid`.

    Returns (problem, result, {"report": ..., "config": ...}): ``report`` is
    :func:`estimates_report`; ``config`` the resolved configuration (defaults included,
    paths absolute), loadable again. ``jacobian``: "ad" or "fd", overriding the file's.
    Raises FileFormatError / DanoError naming the file and the key.
    """
    path = Path(config)
    if path.suffix.lower() not in (".toml", ".json") and not path.exists():
        raise DanoError(f"unknown identification {str(config)!r}: give a TOML problem file or a saved config.json")
    problem, solver, resolved = problem_from_toml(path)
    if jacobian is not None:
        solver["jacobian"] = jacobian
    resolved["options"]["jacobian"] = solver["jacobian"]
    result = identify(problem, **solver_options(solver))
    problem = problem.as_identified(result)  # (the rollouts the answer came from)
    return problem, result, {"report": estimates_report(result), "config": resolved}


def _object_names(objects: list[str]) -> list[str]:
    """Each object's name in a template: its asset's own name (the one a tracked or simulated
    trajectory of it carries), made unique by a suffix ``_2``, ``_3``, ... where repeated."""
    names: list[str] = []
    for o in objects:
        asset = load_asset(o)
        name, k = asset.name, 2
        while name in names:
            name, k = f"{asset.name}_{k}", k + 1
        names.append(name)
    return names


def template(files, tracked: str | None = None, frame_interval: float | None = None) -> str:
    """A commented TOML problem for one's own scene and objects, for ``dano sysid --template``:
    ``files`` are an optional MJCF scene (``.xml``, first) and one or more ``.dano`` assets (or
    ``builtin:NAME``). The scene's time step is the one its MJCF states (else 0.01 s); each
    object is named as its asset names itself (``dano build --name``; what ``dano simulate``
    and ``dano track``'s ``poses.npz`` call it), a repeated name given a suffix ``_2``, ``_3``,
    .... The ``[[trajectory]]`` entries point at
    ``<name>_1.csv`` placeholders whose columns and units the comments give.

    ``tracked``: instead, one object's poses tracked from a video (``dano track``'s
    ``poses.npz``, a path as the TOML file will read it) at ``frame_interval`` [s]: the
    trajectory points at it, the time step is the frame interval (or a whole fraction of it
    no longer than 0.01 s, with ``substeps``), and the ground's height is fitted (the route of
    docs/tracking.md: single shooting from the first frame, its velocity fitted where the
    frames' noise makes finite differences poor; windows of multiple shooting left as a
    commented option: on a new user's mallet slide tracked with 11 mm errors, windows of 10
    frame intervals gave a friction of 0.053 for MuJoCo's 0.4, single shooting 0.408).
    Raises DanoError when no object is given, a file is missing, or ``tracked`` comes with
    more than one object or no positive frame interval; FileFormatError when an object's
    file is not a ``.dano`` asset."""
    files = [str(f) for f in files]
    scene = files[0] if files and files[0].lower().endswith(".xml") else None
    objects = files[1:] if scene else files
    if not objects:
        raise DanoError("--template: give the scene's MJCF (optional) and at least one .dano object, e.g. "
                        "--template scene.xml spot.dano")
    for f in ([scene] if scene else []) + [o for o in objects if not o.startswith("builtin:")]:
        if not Path(f).exists():
            raise DanoError(f"--template: {f}: no such file")
    names = _object_names(objects)
    dt = (stated_timestep(scene) if scene else None) or DEFAULT_DT
    substeps = 1
    if tracked is not None:
        if len(objects) != 1 or not (frame_interval and np.isfinite(frame_interval) and frame_interval > 0):
            raise DanoError("a tracked trajectory's problem needs one object and a positive frame interval, got "
                            f"{len(objects)} objects and {frame_interval}")
        substeps = max(1, int(np.ceil(frame_interval / DEFAULT_DT - 1e-9)))
        dt = frame_interval / substeps
    lines = ["# dano sysid problem (format: docs/sysid.md, every key: docs/config-reference.md).",
             "# Relative paths are read from this file's folder. Run: dano sysid THIS.toml", "", "[scene]"]
    lines += [f'mjcf = {json.dumps(scene)}                 # your MuJoCo scene (its ground, table, robot)'] if scene else [
        "# mjcf = \"scene.xml\"           # left out: an empty world with a ground plane at z = 0"]
    lines += [f"dt = {dt!r}                      # simulation step [s] = frame interval / substeps",
              'contact_model = "centroid"      # or "per_sample" (a force per boundary sample)']
    for name, obj in zip(names, objects):
        lines += ["", "[[scene.object]]", f'name = {json.dumps(name)}', f'asset = {json.dumps(obj)}',
                  "pos = [0.0, 0.0, 0.0]           # world [m]; each trajectory's first pose places it",
                  "quat = [1.0, 0.0, 0.0, 0.0]     # w, x, y, z"]
    lines += ["", "[contact]                        # fixed contact parameters (all pairs); the rest: the paper's",
              "# sliding_drag = 0.0              # held at 0 anyway while sliding_friction is identified"]
    for name in names:
        lines += ["", "[[trajectory]]"] + ([f"file = {json.dumps(tracked)}          # dano track's poses (a dano "
                                            "trajectory)"] if tracked is not None else [
                  f'file = "{name}_1.csv"          # CSV: header t,x,y,z,qw,qx,qy,qz; one row per frame; time [s],',
                  "                                 # centre of mass [m], world frame; orientation quaternion (w first);",
                  "                                 # frames may be missing (rows left out, or a pose left empty).",
                  "                                 # Or a .npz with time (T,) and poses (T, 7), or a dano trajectory"]) + [
                  f'object = {json.dumps(name)}',
                  "velocities = false              # true: start from measured velocities (CSV columns vx,vy,vz",
                  "                                 # world [m/s], wx,wy,wz body [rad/s])",
                  *(["# add one [[trajectory]] per recording"] if tracked is None else
                    ["skip_poor_frames = true         # frames the tracker flagged poor (track.csv) left out as missing",
                     "# (poses tracked from a video by dano track: its world frame is camera.json's, the ground z = 0)"])]
    route = "" if tracked is not None else "# "  # the ground's height: fitted for a tracked video
    lines += ["", "[[parameter]]", 'name = "sliding_friction"       # or impact_spring, impact_damper, torsional_friction,',
              "                                 # rolling_friction, com_offset_x|y|z, ...; alpha (mass scale) only",
              "                                 # where something of known mass pushes the object",
              "initial = 0.5", "lower = 0.0", "upper = 2.0",
              "", "[options]                        # all optional; the defaults shown"
              + (", but for those a tracked video's route sets" if tracked is not None else ""),
              f"{'' if substeps > 1 else '# '}substeps = {substeps}".ljust(35)
              + "# tosses, drops, bounces: dt a few ms (2.5 ms for a 0.2 m, 0.7 kg",
              "                                   # tumbling object: docs/own-object.md §4), substeps to match",
              "# auto_windows = true              # tosses, drops: a window from just before each observed impact",
              "                                   # (docs/own-object.md §4); an object that rolls or tumbles as it lands",
              "                                   # bounds its friction from below only: add slides on a face",
              '# fit_velocity = "auto"            # nuisance: each start\'s velocity along these axes;',
              '                                   # auto: "xyz" where the frames\' noise makes finite differences poor',
              '                                   # or the first frame disagrees with the next ones',
              '# fit_position = ""                # nuisance: each start\'s position axes, e.g. "xy" for noisy starts',
              "# scan = 15                         # a global scan first (left out: automatic; 0: off)",
              "# profile_points = 32               # verify the estimate and give its interval (0: off)",
              "# level = 0.95                      # the interval's level",
              "# poses tracked from a video (dano track): docs/tracking.md",
              f"{route}fit_ground = true                 # the ground's height (tracking errors along the camera axis)",
              "# window = 10                      # multiple shooting: each 10 frame intervals restarted from their",
              '# fit_velocity = "xyz"              # first frame, its velocity fitted: for a tracked motion that',
              "                                   # tumbles; a slide tracked with mm errors loses its friction in",
              "                                   # short windows, and tosses take auto_windows instead (windows",
              "                                   # across impacts: a mug's friction 0.72 for MuJoCo's 0.5)",
              '# fit_angular_velocity = "xyz"      # and each start\'s angular velocity, for an object that tumbles',
              "                                   # or spins (6 more parameters per window: slower, often not needed)"]
    return "\n".join(lines) + "\n"
