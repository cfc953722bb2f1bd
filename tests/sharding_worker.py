"""Worker processes for tests/test_sharding.py: the device count and jax.distributed must be
set before JAX starts, so these checks run in processes of their own.

``python sharding_worker.py devices OUT.json`` (with
``XLA_FLAGS=--xla_force_host_platform_device_count=8``): batched rollouts, the identification
residual, its Jacobian and the scan's batch, each split over 2 and 8 devices and on one
device; writes their largest differences.

``python sharding_worker.py identify OUT.json DATA_DIR [PORT PROCESSES PROCESS_ID]``: identify
the sliding friction from the trajectory files in DATA_DIR, each process loading only its
share of them (:func:`dano.sharding.load_shares`); with PORT, as one process of a
``jax.distributed`` run whose coordinator is 127.0.0.1:PORT (CPU collectives by gloo).
"""

import dataclasses
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("NPROC", "1")  # one XLA thread per process, as the command line


def box_scene():
    """A 10 x 10 x 5 cm box DANO (400 samples) on the ground, 2.5 ms steps."""
    from dano.asset import build
    from dano.fields import BoxField
    from dano.sim import DanoObject, compose

    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=0,
                  name="box")
    return compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.0025)


def slide_problem(scene, observations):
    """Sliding friction from Coulomb slides observed at 100 Hz (4 substeps per frame)."""
    from dano.sysid import FitParameter, SysIdProblem, Weights

    return SysIdProblem(scene, observations, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                        weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4)


def load_observation(path):
    """One trajectory file (time, poses of the box, qvel0) as an Observation."""
    import numpy as np

    from dano.sysid import Observation

    with np.load(path) as f:
        return Observation(time=f["time"], poses={"box": f["poses"]}, qvel0=f["qvel0"], name=Path(path).stem)


#: the identification both runs make: the local solve from the guess (one compiled residual
#: and Jacobian) and the scan's batch at these friction values
IDENTIFY = dict(scan=0, profile_points=0)
SCAN_FRICTIONS = [[0.1], [0.3], [0.45], [0.8]]


def identify_report(problem) -> dict:
    import jax
    import numpy as np

    from dano.sysid import identify

    t0 = time.perf_counter()
    result = identify(problem, **IDENTIFY)
    costs = 0.5 * np.sum(problem.batch_residuals(np.array(SCAN_FRICTIONS)) ** 2, axis=1)
    return {"process": jax.process_index(), "processes": jax.process_count(), "devices": jax.device_count(),
            "observations": [o.name for o in problem.observations], "estimates": result.estimates.tolist(),
            "final_cost": result.final_cost, "success": bool(result.success), "nfev": result.nfev,
            "scan_costs": costs.tolist(), "wall_time_s": time.perf_counter() - t0}


def devices_check() -> dict:
    import jax
    import numpy as np

    from dano import sharding
    from dano.experiments.sysid_examples import analytic_slides
    from dano.sim import State, rollout_arrays

    out = {"devices": jax.device_count(), "xla_flags": os.environ.get("XLA_FLAGS", "")}
    scene = box_scene()
    params = scene.default_params()
    rng = np.random.default_rng(0)
    B = 5  # divides none of 2, 3, 8: padded
    qpos = np.tile(np.r_[0.0, 0.0, 0.08, 1.0, 0.0, 0.0, 0.0], (B, 1))
    qvel = rng.normal(0.0, 0.5, (B, 6))
    run = sharding.sharded_vmap(lambda q, v: rollout_arrays(scene, State(q, v), None, params, 40)[:2])
    problem = slide_problem(scene, analytic_slides(0, 0.05, 3, frames=12))
    theta = problem.initial()
    thetas = np.array([[0.2], [0.3], [0.45], [0.6], [0.9]])
    with sharding.use_devices(1):
        ref = [np.asarray(x) for x in run(qpos, qvel)]
        r1, J1 = problem.residuals_and_jacobian(theta)
        B1 = problem.batch_residuals(thetas)
    for n in (2, 8):
        with sharding.use_devices(n):
            got = [np.asarray(x) for x in run(qpos, qvel)]
            r, J = problem.residuals_and_jacobian(theta)
            Bn = problem.batch_residuals(thetas)
        out[f"devices_{n}"] = {
            "rollout_shapes": [list(x.shape) for x in got],
            "rollout_max_abs_diff": max(float(np.max(np.abs(a - b))) for a, b in zip(got, ref)),
            "residual_max_abs_diff": float(np.max(np.abs(r - r1))),
            "jacobian_max_abs_diff": float(np.max(np.abs(J - J1))),
            "scan_max_abs_diff": float(np.max(np.abs(Bn - B1))),
            "shapes": [list(r.shape), list(J.shape), list(Bn.shape)],
        }
    # the 8-device programs again, from disk: forget the loaded programs, load them (dano._compiled)
    from dano import _compiled

    loaded = _compiled.COUNTS["loaded"]
    _compiled.clear()
    problem = dataclasses.replace(problem)  # a new problem: not its kept last evaluation at θ
    with sharding.use_devices(8):
        r, J = problem.residuals_and_jacobian(theta)
        Bn = problem.batch_residuals(thetas)
    out["reloaded"] = {"programs_loaded": _compiled.COUNTS["loaded"] - loaded,
                       "export_directory": str(_compiled.directory()),
                       "max_abs_diff": max(float(np.max(np.abs(r - r1))), float(np.max(np.abs(J - J1))),
                                           float(np.max(np.abs(Bn - B1))))}
    out["reference"] = {"rollout_shapes": [list(x.shape) for x in ref],
                        "shapes": [list(r1.shape), list(J1.shape), list(B1.shape)],
                        "rollout_spread": float(np.ptp(ref[0][:, -1, 0])),  # the rows differ: padding would show
                        "jacobian_norm": float(np.linalg.norm(J1)), "finite": bool(np.all(np.isfinite(B1)))}
    return out


def main(argv: list[str]) -> None:
    mode, out = argv[0], Path(argv[1])
    if mode == "identify" and len(argv) > 3:
        from dano import sharding

        sharding.initialize(f"127.0.0.1:{argv[3]}", int(argv[4]), int(argv[5]))  # before JAX starts
    import dano

    dano.enable_float64()
    dano.enable_compilation_cache()
    if mode == "devices":
        report = devices_check()
    else:
        from dano import sharding

        files = sorted(str(p) for p in Path(argv[2]).glob("*.npz"))
        problem = slide_problem(box_scene(), sharding.load_shares(files, load_observation))
        report = identify_report(problem)
        report["loaded_here"] = [Path(files[i]).name for i in sharding.share(len(files))]
    out.write_text(json.dumps(report))


if __name__ == "__main__":
    main(sys.argv[1:])
