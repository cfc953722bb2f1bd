"""Identification runs from a configuration (a TOML file or a built-in example name).

Built-in examples: ``soap`` (the paper's real soap video) and ``bunny-pushes`` (the paper's
interactive-perception experiment). A TOML file describes a user problem::

    [scene]
    mjcf = "table.xml"            # optional; default: empty world with a ground plane
    dt = 0.01                     # simulation step [s] = frame interval / substeps
    contact_model = "centroid"    # or "per_sample"
    [[scene.object]]
    name = "soap"
    asset = "soap.dano"           # or "builtin:bluesoap"
    pos = [0.0, 0.0, 0.4]
    quat = [1.0, 0.0, 0.0, 0.0]

    [contact]                     # fixed contact parameters (all pairs); the rest: paper defaults
    sliding_drag = 0.0

    [[trajectory]]
    file = "run1.csv"             # CSV columns t,x,y,z,qw,qx,qy,qz (header line), or a dano .npz
    object = "soap"               # which DANO the CSV tracks

    [[parameter]]
    name = "sliding_friction"     # a contact parameter or "alpha"
    initial = 0.3
    lower = 0.0
    upper = 2.0
    # target = "soap/ground"      # one pair (or DANO for alpha); default all

    [options]
    substeps = 1
    fit_velocity = "xy"           # nuisance initial velocity axes
    window = 0                    # >0: multiple shooting windows of this many frames
    horizons = []                 # continuation, e.g. [0.4]
    position_weights = [1.0, 1.0, 1.0]
    rotation_weight = 1.0
    jacobian = "ad"

Relative paths are resolved against the file's folder. Everything resolved is returned
so that it can be saved next to the results.
"""

from __future__ import annotations

import tomllib
from pathlib import Path

import numpy as np

from ..errors import DanoError, FileFormatError
from .problem import FitParameter, Observation, SysIdProblem, Weights
from .solve import identify

EXAMPLES = ("soap", "bunny-pushes")


def _read_trajectory(path: Path, obj: str | None, scene) -> Observation:
    if not path.is_file():
        raise FileFormatError(f"{path}: no such trajectory file")
    if path.suffix.lower() == ".csv":
        try:
            data = np.genfromtxt(path, delimiter=",", names=True)
        except Exception as exc:
            raise FileFormatError(f"{path}: cannot read CSV ({exc})") from exc
        cols = ("t", "x", "y", "z", "qw", "qx", "qy", "qz")
        if data.dtype.names is None or any(c not in data.dtype.names for c in cols):
            raise FileFormatError(f"{path}: CSV needs a header with columns {', '.join(cols)}")
        if obj is None:
            raise DanoError(f"{path}: say which object the CSV tracks (object = \"name\")")
        poses = np.stack([data[c] for c in cols[1:]], axis=1)
        return Observation(time=np.asarray(data["t"]), poses={obj: poses}, name=path.name)
    from ..trajectory import load_trajectory

    traj = load_trajectory(path)
    names = [obj] if obj else list(traj.dano_names)
    poses = {}
    for n in names:
        if n not in traj.dano_names:
            raise DanoError(f"{path}: no DANO {n!r} in the trajectory (it has {list(traj.dano_names)})")
        poses[n] = np.concatenate(traj.dano_pose(n), axis=1)
    return Observation(time=traj.time, poses=poses, name=path.name)


def problem_from_toml(path: str | Path) -> tuple[SysIdProblem, dict, dict]:
    """Build the problem described by a TOML file; returns (problem, solver options,
    resolved configuration). Raises FileFormatError / DanoError naming the file."""
    from ..asset import load
    from ..data import load_builtin
    from ..sim.scene import DanoObject, compose

    path = Path(path)
    try:
        cfg = tomllib.loads(path.read_text())
    except FileNotFoundError:
        raise FileFormatError(f"{path}: no such configuration file") from None
    except tomllib.TOMLDecodeError as exc:
        raise FileFormatError(f"{path}: not valid TOML ({exc})") from exc
    base = path.parent
    try:
        sc = cfg["scene"]
        objects = []
        for o in sc["object"]:
            src = o["asset"]
            asset = load_builtin(src.split(":", 1)[1]) if src.startswith("builtin:") else load(base / src)
            objects.append(DanoObject(o["name"], asset, tuple(o.get("pos", (0, 0, 0))),
                                      tuple(o.get("quat", (1, 0, 0, 0)))))
        mjcf = base / sc["mjcf"] if "mjcf" in sc else None
        scene = compose(objects, mjcf, dt=float(sc["dt"]), ground=None if mjcf else True, name=path.stem,
                        contact_model=sc.get("contact_model", "centroid"))
        contact = cfg.get("contact", {})
        if not isinstance(contact, dict):
            raise DanoError("[contact] must be a table of contact parameter = value")
        try:
            base_params = scene.default_params(**{k: float(v) for k, v in contact.items()})
        except (TypeError, ValueError) as exc:
            raise DanoError(f"[contact]: values must be numbers ({exc})") from None
        obs = [_read_trajectory(base / t["file"], t.get("object"), scene) for t in cfg["trajectory"]]
        params = [FitParameter(p["name"], float(p["initial"]), float(p.get("lower", 0.0)),
                               float(p.get("upper", np.inf)), p.get("target")) for p in cfg.get("parameter", [])]
        opt = cfg.get("options", {})
        weights = Weights(tuple(opt.get("position_weights", (1.0, 1.0, 1.0))), float(opt.get("rotation_weight", 1.0)))
        problem = SysIdProblem(scene, obs, params, weights, base_params=base_params,
                               substeps=int(opt.get("substeps", 1)),
                               fit_velocity=opt.get("fit_velocity", ""), window=opt.get("window") or None)
    except KeyError as exc:
        raise FileFormatError(f"{path}: missing entry {exc}") from exc
    except DanoError as exc:
        raise DanoError(f"{path}: {exc}") from exc
    solver = {"jacobian": opt.get("jacobian", "ad"), "horizons": tuple(opt.get("horizons", ()))}
    return problem, solver, {"config_file": str(path), **cfg}


def run(config: str | Path, *, jacobian: str | None = None, noise: bool = True) -> tuple[SysIdProblem, object, dict]:
    """Run an identification: ``config`` is a built-in example name or a TOML file.

    Returns (problem, result, report); ``report`` is JSON-able: the estimates as top-level
    keys (e.g. ``sliding_friction``), their standard errors (``<name>_std``), wall and
    compile times, the fit residual and, for the soap, its sensitivity to the assumed
    length scale. ``noise``: for ``bunny-pushes``, add the paper's pose noise (1 mm, 0.5°).
    """
    from .examples import PUSH_GUESS, PUSH_TRUTH, push_problem, soap_problem

    extra: dict = {}
    if config == "soap":
        problem, solver = soap_problem(substeps=4), {"jacobian": "ad", "horizons": ()}
        resolved = {"example": "soap", "substeps": 4, "length_scale": 1.0,
                    "data": "soap_pose_traj.csv (real video, 120 fps) + bluesoap collider (paper)",
                    "time_scale": "Froude: sqrt(15.342) s of simulation per s of video",
                    "fit": ["sliding_friction (soap/ground)", "initial velocity x, y (nuisance)"],
                    "weights": {"position": [1, 1, 0], "rotation": 0}}
    elif config == "bunny-pushes":
        noise_levels = (1e-3, 0.5) if noise else (0.0, 0.0)
        problem, solver = push_problem(*noise_levels), {"jacobian": "ad", "horizons": (0.4,)}
        resolved = {"example": "bunny-pushes", "truth": PUSH_TRUTH, "initial_guess": PUSH_GUESS,
                    "noise": {"position_m": noise_levels[0], "rotation_deg": noise_levels[1]}, "pushes": 10,
                    "horizons": [0.4]}
        extra["truth"] = PUSH_TRUTH
    else:
        path = Path(config)
        if path.suffix.lower() != ".toml" and not path.exists():
            raise DanoError(f"unknown identification {config!r}: give a TOML file or one of {', '.join(EXAMPLES)}")
        problem, solver, resolved = problem_from_toml(path)
    if jacobian is not None:
        solver["jacobian"] = jacobian
    resolved["solver"] = {**solver, "method": "scipy.optimize.least_squares (trf), bounds"}
    result = identify(problem, jacobian=solver["jacobian"], horizons=solver["horizons"])
    report = {}
    for label, v, s in zip(result.labels, result.estimates, result.standard_errors):
        if not label.startswith("v0["):
            key = label.split(":")[-1] if sum(lab.split(":")[-1] == label.split(":")[-1]
                                              for lab in result.labels) == 1 else label
            report[key], report[f"{key}_std"] = float(v), float(s)
    report.update(result.as_dict())
    report.update(extra)
    if config == "soap":
        sens = {}
        for scale in (0.9, 1.1):
            r = identify(soap_problem(length_scale=scale, substeps=4))
            sens[str(scale)] = float(r.estimates[0])
        mu = report["sliding_friction"]
        report["length_scale_sensitivity"] = {
            "sliding_friction_at_length_scale": {"0.9": sens["0.9"], "1.0": mu, "1.1": sens["1.1"]},
            "elasticity_dlnmu_dlnL": float((np.log(sens["1.1"]) - np.log(sens["0.9"])) / (np.log(1.1) - np.log(0.9))),
            "note": "friction is identified together with the assumed real length per scene unit; "
                    "scaling all displacements by L scales the identified friction by about L^elasticity",
        }
        report["paper_reference"] = {"video_identification": 0.61, "tilted_plane": 0.75}
    return problem, result, {"report": report, "config": resolved}
