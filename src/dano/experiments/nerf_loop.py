"""The ground-truth loop: does a DANO made from images of a mesh match the mesh?

The paper claims DANOs from images simulate "nearly indistinguishably" from ground truth;
this makes it a number. A mesh is rendered (:func:`~dano.nerf.synthetic.render_dataset`),
a field is trained on the views, DANOs are built with each σ -> density rule and compared
with the mesh's exact mass properties (trimesh, equal density) and, in simulation, with
the DANO of the mesh itself (:func:`dano.fields.mesh_field`) in a drop, a high-friction
slide (the bunny tips over in it) and four level slides at the paper's default friction.
"""

from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ..asset import build
from ..fields import mesh_field
from ..io import load_mesh
from ..sim import rollout
from ..sim.scene import DanoObject, compose
from ..sim.scenes import PAPER_DROP_QUAT, initial_state, resting_height
from ..tracking.track import pose_errors
from ..nerf.data import load_dataset
from ..nerf.density import DENSITY_RULES, density_grid
from ..nerf.synthetic import render_dataset
from ..nerf.train import TrainConfig, train


def mass_property_errors(asset, mesh, rule: str) -> dict:
    """Errors of a DANO's mass properties against a watertight trimesh ``mesh`` (same frame).

    The DANO is built with α = 1 from a rule's density (``solid``/``occupancy``: values in
    [0, 1], so its mass is a volume; ``sigma``: divided by the 99th-percentile σ inside).
    Returns mass_error (relative, equal density), com_error (|Δc| / the mesh's bounding-box
    diagonal), inertia_error (‖ΔJ‖_F / ‖J‖_F at equal density) and inertia_error_equal_mass.
    """
    size = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    volume = float(mesh.volume)
    inertia_mesh = np.asarray(mesh.moment_inertia)  # density 1, about the centre of mass
    unit = 1.0
    if rule == "sigma":  # σ as a density: its "full occupancy" is the 99th percentile inside
        values = np.asarray(asset.field.values)
        unit = float(np.percentile(values[values > 0.01 * values.max()], 99))
    mass = asset.mass / unit
    inertia = asset.inertia / unit
    return {
        "mass_error": mass / volume - 1.0,
        "com_error": float(np.linalg.norm(asset.center_of_mass - mesh.center_mass)) / size,
        "inertia_error": float(np.linalg.norm(inertia - inertia_mesh) / np.linalg.norm(inertia_mesh)),
        "inertia_error_equal_mass": float(np.linalg.norm(inertia * volume / mass - inertia_mesh)
                                          / np.linalg.norm(inertia_mesh)),
    }


#: the level slides: the paper's default sliding friction (``bunny-slide``), thrown upright
#: at 1.5 m/s along four directions in the ground plane [deg from +x]
LEVEL_SLIDE_FRICTION = 0.2
LEVEL_SLIDE_DIRECTIONS_DEG = (0, 90, 180, 270)
#: every simulated run: the drop, the high-friction slide and the level slides
SIMULATION_KINDS = ("drop", "slide") + tuple(f"slide_{d}deg" for d in LEVEL_SLIDE_DIRECTIONS_DEG)


def _final_pose(asset, kind: str, scale: float, duration: float = 2.0):
    """Final (CoM position, quaternion) of ``asset`` scaled by ``scale`` at 1 kg on the ground
    (h = 0.01 s): ``drop``, dropped tumbling (friction 0.3); ``slide``, thrown upright along
    +x at 1.5 m/s with friction 0.3 (the bunny tips over forwards: a bifurcation that
    amplifies any difference); ``slide_<d>deg``, thrown upright at 1.5 m/s along the direction
    d [deg from +x] with friction :data:`LEVEL_SLIDE_FRICTION`."""
    a = asset.scaled(scale).with_mass(1.0)
    friction = 0.3
    if kind == "drop":
        pos, quat, vel, omega = (0, 0, 0.35), PAPER_DROP_QUAT, (0.4, 0.4, 0.2), (0.5, 1.0, 1.0)
    elif kind == "slide":
        pos, quat, vel, omega = (0, 0, resting_height(a)), (1, 0, 0, 0), (1.5, 0, 0), (0, 0, 0)
    elif kind.startswith("slide_") and kind.endswith("deg") and kind[len("slide_"):-len("deg")].isdigit():
        d = np.radians(float(kind[len("slide_"):-len("deg")]))
        pos, quat, omega = (0, 0, resting_height(a)), (1, 0, 0, 0), (0, 0, 0)
        vel = (1.5 * np.cos(d), 1.5 * np.sin(d), 0)
        friction = LEVEL_SLIDE_FRICTION
    else:
        raise ValueError(f"unknown run {kind!r}; one of {', '.join(SIMULATION_KINDS)}")
    scene = compose([DanoObject("object", a, pos, quat)], dt=0.01, name=f"loop-{kind}")
    state = initial_state(scene, {"object": (pos, quat)}, {"object": (vel, omega)})
    traj = rollout(scene, state, params=scene.default_params(sliding_friction=friction), steps=int(duration / 0.01))
    p, q = traj.dano_pose("object")
    return p[-1], q[-1]


def final_poses(asset, scale: float) -> dict:
    """{kind: (CoM position (3,) [m], quaternion (4,) wxyz)} at the end of each of
    :func:`_final_pose`'s runs (:data:`SIMULATION_KINDS`)."""
    return {kind: _final_pose(asset, kind, scale) for kind in SIMULATION_KINDS}


def simulation_difference(asset, reference: dict, scale: float, size: float) -> dict:
    """Final-pose differences of ``asset`` scaled by ``scale`` to 1 kg from ``reference``
    (:func:`final_poses` of the mesh DANO), per run: ``<kind>_position_error``, position /
    (size·scale), and ``<kind>_rotation_error_deg``; over the level slides also
    ``level_slides_position_error_max`` and ``level_slides_rotation_error_deg_max``."""
    out = {}
    for kind, (pb, qb) in reference.items():
        pa, qa = _final_pose(asset, kind, scale)
        out[f"{kind}_position_error"] = float(np.linalg.norm(pa - pb)) / (size * scale)
        out[f"{kind}_rotation_error_deg"] = float(pose_errors(np.r_[pa, qa][None], np.r_[pb, qb][None])[1][0])
    level = [f"slide_{d}deg" for d in LEVEL_SLIDE_DIRECTIONS_DEG if f"slide_{d}deg" in reference]
    if level:
        out["level_slides_position_error_max"] = max(out[f"{k}_position_error"] for k in level)
        out["level_slides_rotation_error_deg_max"] = max(out[f"{k}_rotation_error_deg"] for k in level)
    return out


def ground_truth_loop(mesh_path: str | Path, minutes: float = 3.0, views: int = 100, size: int = 100,
                      resolution: int = 96, sim_size: float = 0.2, config: TrainConfig | None = None,
                      work_dir: str | Path | None = None) -> dict:
    """Render ``mesh_path``, train a field for ``minutes``, build DANOs with every rule and
    compare them with the mesh: a JSON-able dict (per rule: mass/CoM/inertia errors and the
    differences (:func:`simulation_difference`) from the mesh DANO, simulated at ``sim_size``
    [m] across)."""
    with tempfile.TemporaryDirectory(dir=work_dir) as tmp:
        folder = Path(tmp) / "views"
        t0 = time.perf_counter()
        render_dataset(mesh_path, folder, views=views, size=size)
        data = load_dataset(folder)
    render_s = time.perf_counter() - t0
    config = config or TrainConfig(minutes=minutes, background="random")
    train_set, held = data.split(max(1, views // 10))
    result = train(train_set, config, heldout=held)
    step = float(np.linalg.norm(data.bounds[1] - data.bounds[0])) / config.samples_across
    report = {"mesh": Path(mesh_path).name, "views": views, "size_px": size, "render_s": render_s,
              "psnr_heldout": result.psnr_heldout, "train_wall_time_s": result.wall_time_s,
              "rays_per_s": result.rays_per_s}
    report.update(compare_with_mesh(result.field, result.occupancy, mesh_path, step, resolution, sim_size))
    return report


def compare_with_mesh(field, occupancy, mesh_path: str | Path, step: float, resolution: int = 96,
                      sim_size: float = 0.2) -> dict:
    """DANOs built from a trained ``field`` (field units = the mesh's) with every σ → density
    rule, compared with the mesh: {"mesh_field_dano": its own DANO's errors,
    "mesh_field_dano_other_seeds": simulated differences of mesh DANOs with other sample seeds
    (the floor of that metric), "rules": {rule: mass/CoM/inertia errors, the solid rule's
    surface calibration, simulated differences}}.
    ``step``: the field's render sample step [field units]; ``occupancy``: its grid or None."""
    mesh = load_mesh(mesh_path)
    diag = float(np.linalg.norm(mesh.bounds[1] - mesh.bounds[0]))
    exact = mesh_field(mesh_path)
    reference = build(exact, alpha=1.0, num_samples=5000, seed=0, name="mesh")
    report = {"mesh_field_dano": mass_property_errors(reference, mesh, "solid"), "rules": {}}
    reference_poses = final_poses(reference, sim_size / diag)
    # the metric's floor: mesh DANOs that differ from the reference only in their random samples
    report["mesh_field_dano_other_seeds"] = [
        simulation_difference(build(exact, alpha=1.0, num_samples=5000, seed=seed, name="mesh"), reference_poses,
                              sim_size / diag, diag) for seed in (1, 2)]
    variants = [(rule, rule, {}) for rule in DENSITY_RULES]
    variants.append(("solid_uncalibrated", "solid", {"calibrate": False}))
    for rule_name, rule, options in variants:
        grid, info = density_grid(field, rule, resolution=resolution, step=step, occupancy=occupancy, details=True,
                                  **options)
        asset = build(grid, alpha=1.0, num_samples=5000, seed=0, name=f"images-{rule_name}")
        entry = mass_property_errors(asset, mesh, rule)
        entry.update(info)
        entry.update(simulation_difference(asset, reference_poses, sim_size / diag, diag))
        report["rules"][rule_name] = entry
    for opacity in (0.3, 0.7):  # how much the solid rule's surface level matters, calibrated
        grid = density_grid(field, "solid", resolution=resolution, step=step, surface_opacity=opacity,
                            occupancy=occupancy)
        asset = build(grid, alpha=1.0, num_samples=5000, seed=0, name=f"images-solid-{opacity}")
        report["rules"][f"solid_surface_opacity_{opacity}"] = mass_property_errors(asset, mesh, "solid")
    return report
