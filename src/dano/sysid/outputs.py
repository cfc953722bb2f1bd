"""An identification's outputs: the JSON report of its estimates, the fit plot, and the
result folder (``result.json``, ``config.json``, ``fit.png``: all three or none)."""

from __future__ import annotations

import json
from collections.abc import Callable
from contextlib import ExitStack
from pathlib import Path

import numpy as np

from .._files import atomic_path, config_json
from ..pose import quat_error
from ..viz.plot import plot_sysid
from .problem import SEGMENT_NUISANCE_PREFIXES


def estimates_report(result) -> dict:
    """A JSON-able report of an identification: the estimates as top-level keys (e.g.
    ``sliding_friction``; the pair or object prefix kept only where a name occurs twice),
    ``<name>_std``, ``<name>_lower``/``<name>_upper`` where there is an interval, then
    everything :meth:`SysIdResult.as_dict` holds. Per-segment nuisance parameters are in
    ``parameters`` only."""
    report = {}
    for label, v, s in zip(result.labels, result.estimates, result.standard_errors):
        if not label.startswith(SEGMENT_NUISANCE_PREFIXES):
            key = label.split(":")[-1] if sum(lab.split(":")[-1] == label.split(":")[-1]
                                              for lab in result.labels) == 1 else label
            report[key], report[f"{key}_std"] = float(v), float(s)
            if result.interval is not None and label in result.interval["lower"]:
                report[f"{key}_lower"] = result.interval["lower"][label]
                report[f"{key}_upper"] = result.interval["upper"][label]
    report.update(result.as_dict())
    return report


def fit_plot(problem, result, path, max_trajectories: int = 4) -> Path:
    """Observed vs fitted positions of the first ``max_trajectories`` trajectories (each with
    every window of its multiple shooting, a fitted line per window), their rotations from
    the first frame where the fit weighs rotations, the cost per iteration and the profiles
    of ``result`` (:func:`dano.viz.plot_sysid`), titled with each estimate and its interval
    (or standard error), to an image file."""
    rotations = problem.weighs_rotations()  # (the rotation panel where the fit weighs them)
    windows: dict[int, list] = {}
    for i, seg in enumerate(problem.segments):
        windows.setdefault(seg.obs, []).append((i, seg))
    series = []
    for o in list(windows)[:max_trajectories]:
        obs, segs = problem.observations[o], windows[o]
        first, last = min(s.start for _, s in segs), max(s.start + s.frames for _, s in segs)
        time = np.asarray(obs.time)
        for name, poses in obs.poses.items():
            a = problem.scene.qpos_adr[problem.scene.dano_index(name)]
            poses = np.asarray(poses)[first:last]  # (finite, unit quaternions: checked where observed)
            pieces = [(time[s.start : s.start + s.frames], np.asarray(result.fitted[i])[:, a : a + 7])
                      for i, s in segs if i < len(result.fitted) and result.fitted[i] is not None]
            gap = (np.full(1, np.nan), np.full((1, 7), np.nan))  # (a break in the line between windows)
            fitted = np.concatenate([x for p in pieces for x in (p[1], gap[1])]) if pieces else None
            series.append({"label": obs.name or str(o), "time": time[first:last], "observed": poses[:, :2],
                           "fitted": None if fitted is None else fitted[:, :2],
                           "fitted_time": np.concatenate([x for p in pieces for x in (p[0], gap[0])]) if pieces
                           else None,
                           **({"observed_angle": _angle_from(poses[0, 3:7], poses[:, 3:7]),
                               "fitted_angle": None if fitted is None else _angle_from(poses[0, 3:7], fitted[:, 3:7])}
                              if rotations else {})})
    profiles = {label: {**prof, "estimate": result.estimates[result.labels.index(label)]}
                for label, prof in (result.scan or {}).get("profile", {}).items()}
    interval = result.interval or {"lower": {}, "upper": {}, "level": 0.95}

    def shown(k, v, s):  # the interval where there is one (it is the uncertainty), else the standard error
        if k in interval["lower"]:
            return f"{k} = {v:.4g} [{interval['lower'][k]:.4g}, {interval['upper'][k]:.4g}] ({interval['level']:.0%})"
        return f"{k} = {v:.4g} ± {s:.2g}"

    title = ", ".join(shown(k, v, s) for k, v, s in zip(result.labels, result.estimates, result.standard_errors)
                      if not k.startswith(SEGMENT_NUISANCE_PREFIXES))
    return plot_sysid(series, result.cost_history, path, profiles=profiles, title=title)


def _angle_from(reference: np.ndarray, quats: np.ndarray) -> np.ndarray:
    """(T,) the rotation angle [deg] of each quaternion (T, 4) wxyz from ``reference`` (4,)
    (NaN where a quaternion is not finite or zero: a break between windows of the fitted line)."""
    ok = np.all(np.isfinite(quats), axis=1) & (np.linalg.norm(np.nan_to_num(quats), axis=1) > 0)
    out = np.full(len(quats), np.nan)
    if ok.any():
        out[ok] = np.degrees(np.linalg.norm(quat_error(np.broadcast_to(reference, quats[ok].shape), quats[ok]),
                                            axis=1))
    return out


def write_outputs(out_dir: str | Path, report: dict | Callable[[], dict], resolved: dict, problem,
                  result) -> list[Path]:
    """``result.json`` (``report``), ``config.json`` (``resolved``, loadable again by
    ``dano sysid``) and ``fit.png`` (:func:`fit_plot`) in ``out_dir``: all three or none.
    ``report`` may be a function of no argument returning it: it is called after the fit is
    drawn, so that work it waits for (studies beside the result) runs meanwhile.
    Returns the paths written."""
    out_dir = Path(out_dir)
    names = ("result.json", "config.json", "fit.png")
    with ExitStack() as stack:
        paths = {n: stack.enter_context(atomic_path(out_dir / n)) for n in names}
        fit_plot(problem, result, paths["fit.png"])
        paths["config.json"].write_text(config_json(resolved))
        paths["result.json"].write_text(json.dumps(report() if callable(report) else report, indent=2))
    return [out_dir / n for n in names]
