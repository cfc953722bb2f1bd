"""The tables ``dano`` prints (rich), one per verb's result."""

from __future__ import annotations

from pathlib import Path

import numpy as np
from rich.markup import escape
from rich.table import Table


def asset_table(asset) -> Table:
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


def simulation_table(setup, traj, wall: float) -> Table:
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


#: nuisance offsets of the segments' starts (SysIdProblem.labels), by label prefix
_START_OFFSETS = {"v0[": "start velocity offsets [m/s]", "w0[": "start angular velocity offsets [rad/s]",
                  "p0[": "start position offsets [m]", "r0[": "start rotation offsets [rad]"}
#: more nuisance parameters than this are summarised, one row per kind
MAX_NUISANCE_ROWS = 6


def sysid_table(config: str, problem, result, report: dict, out_dir: Path) -> Table:
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
    interval = result.interval or {"lower": {}, "upper": {}, "level": 0.95}
    # the calibrated interval (profile likelihood, bootstrap) is the uncertainty where there is
    # one; the standard error (the local curvature) can be far narrower (docs/sysid.md)
    for c in ("parameter", "estimate", f"{interval['level']:.0%} interval", "std. error", "initial"):
        t.add_column(c)
    rows = list(zip(result.labels, result.estimates, result.standard_errors, result.initial))
    nuisance = [r for r in rows if r[0][:3] in _START_OFFSETS]
    many = len(nuisance) > MAX_NUISANCE_ROWS
    for lab, v, sd, x0 in rows:
        if many and lab[:3] in _START_OFFSETS:
            continue
        inside = (f"[{interval['lower'][lab]:.4g}, {interval['upper'][lab]:.4g}]" if lab in interval["lower"]
                  else "-")
        t.add_row(lab, f"{v:.5g}", inside, f"{sd:.2g}", f"{x0:.4g}")
    if many:  # one row per kind of start offset (every value is in result.json)
        for prefix, what in _START_OFFSETS.items():
            values = [(abs(v), lab) for lab, v, _, _ in nuisance if lab.startswith(prefix)]
            if values:
                largest, where = max(values)
                t.add_row(escape(f"{prefix[:-1]}[...]: {len(values)} {what}"),
                          escape(f"|max| {largest:.3g} ({where})"), "-", "-", "0")
    t.caption = (f"rms residual {result.rms_residual:.3g} over {result.num_residuals} residuals; "
                 f"{result.nfev} evaluations; {result.wall_time_s:.2f} s (+{result.compile_time_s:.1f} s compile); "
                 f"wrote {out_dir}/result.json, config.json, fit.png")
    return t


def trajopt_table(task: str, report: dict, paths) -> Table:
    t = Table(title=f"trajectory optimisation: {task}")
    t.add_column("quantity")
    t.add_column("value")
    pushed = "object_final_error" if report["task"] == "push" else "bunny_final_error"  # (push: any object)
    keys = ("status", "iterations", pushed, "object_final_speed", "pusher_final_error", "max_constraint_violation",
            "cost")
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
    return t


def compare_table(report) -> Table:
    t = Table(title=f"mesh route vs DANO: {report['source']} (DANO rest height {report['dano']['rest_height']:.4f}, "
                    f"slide {report['dano']['slide_distance']:.4f})")
    for col in ("level", "collider", "comp.", "pieces", "mass err", "CoM err", "inertia err", "rest Δz",
                "tilt [deg]", "slide diverg."):
        t.add_column(col)
    for e in report["levels"]:
        for c, r in e["collision"].items():
            mass = "-" if r["mass_error"] is None else f"{100 * r['mass_error']:+.0f} %"  # (None: no interior density)
            t.add_row(e["label"], c, str(e["components"]), str(r["pieces"]), mass, f"{r['com_error']:.4f}",
                      f"{100 * r['inertia_error']:.1f} %", f"{r['rest_height_error']:+.4f}",
                      f"{r['rest_tilt_deg']:.2f}", f"{r['slide_divergence']:.4f}")
    return t
