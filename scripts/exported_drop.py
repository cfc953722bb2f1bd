"""Drop an exported hull body (MJCF, loaded from the file) in MuJoCo C and the DANO in dano
from the same initial state; print the final pose difference (docs/mesh-route.md).

    python scripts/exported_drop.py [../shared/data/meshes/spot.obj]
"""

import json
import sys
import tempfile
from pathlib import Path

import mujoco
import numpy as np

import dano
from dano.io import export
from dano.experiments.meshroute import Scenario, _advance, _DanoRuns, _quat_angle_deg, _tilt_deg
from dano.sim import rollout
from dano.sim.scenes import PAPER_DROP_QUAT, initial_state


def drop(asset, qpos0, qvel0, seconds=3.0, friction=0.2):
    with tempfile.TemporaryDirectory() as tmp:
        spec = mujoco.MjSpec.from_file(str(export(asset, Path(tmp) / "body.xml", collision="hull")))
    spec.option.timestep = 0.002
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], friction=[friction, 0.005, 0.0001])
    for g in spec.geoms:
        g.friction = [friction, 0.005, 0.0001]
    m = spec.compile()
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = qpos0, qvel0
    mujoco.mj_forward(m, d)
    _advance(m, d, seconds)
    runs = _DanoRuns(asset, Scenario(friction=friction), "centroid")
    st = initial_state(runs.scene, {"dano": (qpos0[:3], qpos0[3:])}, {"dano": (qvel0[:3], qvel0[3:])})
    q = rollout(runs.scene, st, params=runs.params, steps=int(seconds / 0.01)).qpos[-1]
    return {"mujoco_final": d.qpos.tolist(), "dano_final": q.tolist(),
            "position_difference": float(np.linalg.norm(d.qpos[:3] - q[:3])),
            "height_difference": float(d.qpos[2] - q[2]),
            "tilt_difference_deg": _tilt_deg(d.qpos[3:7], q[3:7]),
            "rotation_difference_deg": _quat_angle_deg(d.qpos[3:7], q[3:7])}


def main():
    dano.enable_float64()
    assets = {"bunny": dano.load_builtin("bunny")}
    if len(sys.argv) > 1:
        from dano.fields import mesh_field

        f = mesh_field(sys.argv[1], resolution=64)
        assets["spot"] = dano.build(f, mass=1.0, num_samples=5000, mesh_resolution=64, name="spot")
    out = {}
    for name, a in assets.items():
        size = float(np.ptp(a.points, axis=0).max())
        z = float(-np.min(a.points[:, 2])) + 0.2 * size
        out[name] = {
            "drop": drop(a, np.r_[0, 0, z, 1, 0, 0, 0], np.zeros(6)),
            # the paper's bunny-drop launch, lengths in object sizes
            "tumble": drop(a, np.r_[0, 0, 1.1 * size, PAPER_DROP_QUAT], np.r_[2 * size, 2 * size, size, 0.5, 1, 1]),
        }
    print(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
