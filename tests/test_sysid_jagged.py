"""Global start on a jagged cost (issue 8): a tumbling cube whose landings depend on the
friction, started far from the truth."""

import jax.numpy as jnp
import numpy as np
from scipy.spatial.transform import Rotation

from dano.asset import build
from dano.fields import BoxField
from dano.sim import DanoObject, State, compose, rollout
from dano.sysid import FitParameter, Observation, SysIdProblem, Weights, identify
from dano.sysid.solve import scan_costs


def test_scan_reaches_the_global_minimum_of_a_jagged_cost():
    """A 10 cm cube thrown spinning onto the ground (truth μ = 0.5, simulated): over 201
    friction values the cost has several local minima (which edge lands first changes with
    μ); identification from μ = 1.8 with a 9-point scan ends at the dense scan's minimum."""
    asset = build(BoxField((0.05, 0.05, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="cube")
    scene = compose([DanoObject("cube", asset, (0, 0, 0.3))], dt=0.0025)
    q0 = np.r_[0, 0, 0.3, Rotation.from_rotvec([0.6, 0.4, 0.2]).as_quat(scalar_first=True)]
    v0 = np.r_[2.5, 0.5, -1.0, 8.0, -12.0, 5.0]
    traj = rollout(scene, State(jnp.asarray(q0), jnp.asarray(v0)), None, scene.default_params(sliding_friction=0.5),
                   480)
    obs = Observation(time=np.arange(121) * 0.01, poses={"cube": np.asarray(traj.qpos[::4])}, qvel0=v0)
    problem = SysIdProblem(scene, [obs], [FitParameter("sliding_friction", 1.8, 0.0, 2.0)],
                           weights=Weights((1, 1, 1), 0.1), substeps=4)
    grid = np.linspace(0, 2, 201)
    cost = scan_costs(problem, grid[:, None])
    interior_minima = np.flatnonzero((cost[1:-1] < cost[:-2]) & (cost[1:-1] < cost[2:])) + 1
    assert len(interior_minima) >= 3, grid[interior_minima]  # jagged: a local method can stop in any of them
    res = identify(problem, scan=9, starts=2)
    assert abs(res.estimates[0] - grid[np.argmin(cost)]) < 0.01
    assert res.final_cost <= cost.min() + 1e-9
