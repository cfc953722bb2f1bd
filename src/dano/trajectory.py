"""Trajectories: the one time-series type that simulation, identification and plots share,
and its ``.npz`` file format."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ._files import atomic_write, read_npz
from .errors import DanoError, FileFormatError


@dataclass(frozen=True)
class Trajectory:
    """A simulated (or observed) trajectory of T+1 states.

    time (T+1,) [s]; qpos (T+1, nq); qvel (T+1, nv) (MuJoCo conventions: free joints hold
    the CoM position [m] and wxyz quaternion, then linear velocity (world frame) [m/s] and
    angular velocity (body frame) [rad/s]); psi (T+1, P): overlap of each contact pair
    (mass units) at each state; body_names (nbody,); dano_names (D,) with qpos_adr/dof_adr
    (D,): where each DANO's free joint sits in qpos/qvel; pair_names (P,); metadata:
    JSON-able dict; final_data: the MJX Data after the last step (simulations only; not
    saved), to continue from with act, time and warm starts intact (its state fields:
    :data:`dano.sim.rollout.CARRIED_FIELDS`; ``mjx.forward`` gives the rest for that state).
    """

    time: np.ndarray
    qpos: np.ndarray
    qvel: np.ndarray
    psi: np.ndarray
    body_names: tuple[str, ...]
    dano_names: tuple[str, ...]
    qpos_adr: tuple[int, ...]
    dof_adr: tuple[int, ...]
    pair_names: tuple[str, ...]
    metadata: dict
    final_data: Any = field(default=None, repr=False, compare=False)

    def dano_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]:
        """Position (T+1, 3) [m] and wxyz quaternion (T+1, 4) of a DANO's centre of mass."""
        i = self.dano_names.index(name)
        a = self.qpos_adr[i]
        return self.qpos[:, a : a + 3], self.qpos[:, a + 3 : a + 7]


def save_trajectory(traj: Trajectory, path: str | Path) -> Path:
    """Write a trajectory to ``.npz``: arrays time (T+1,) [s], qpos (T+1, nq), qvel
    (T+1, nv), psi (T+1, P), body_names, dano_names, qpos_adr, dof_adr, pair_names and
    ``metadata`` (JSON string). Written atomically; refuses non-finite data."""

    for k in ("qpos", "qvel", "psi"):
        if not np.all(np.isfinite(getattr(traj, k))):
            raise DanoError(f"refusing to write a trajectory with non-finite {k}")
    arrays = {
        "time": traj.time, "qpos": traj.qpos, "qvel": traj.qvel, "psi": traj.psi,
        "body_names": np.asarray(traj.body_names, dtype=str), "dano_names": np.asarray(traj.dano_names, dtype=str),
        "qpos_adr": np.asarray(traj.qpos_adr, dtype=np.int64), "dof_adr": np.asarray(traj.dof_adr, dtype=np.int64),
        "pair_names": np.asarray(traj.pair_names, dtype=str),
        "metadata": np.asarray(json.dumps({"format": "dano-trajectory", "version": 1, **traj.metadata})),
    }
    path = Path(path)
    atomic_write(path, lambda f: np.savez_compressed(f, **arrays))
    return path


def load_trajectory(path: str | Path) -> Trajectory:
    """Read a trajectory written by :func:`save_trajectory`. Raises FileFormatError."""
    path = Path(path)
    a = read_npz(path, ("time", "qpos", "qvel"), "trajectory")
    try:
        meta = json.loads(str(a["metadata"])) if "metadata" in a else {}
    except ValueError as exc:
        raise FileFormatError(f"{path}: corrupt metadata ({exc})") from exc
    T = len(a["time"])
    psi = a.get("psi", np.zeros((T, 0)))
    if a["qpos"].shape[0] != T or a["qvel"].shape[0] != T or psi.shape[0] != T:
        raise FileFormatError(f"{path}: time {a['time'].shape}, qpos {a['qpos'].shape}, qvel {a['qvel'].shape}, "
                              f"psi {psi.shape} disagree")
    tup = lambda k: tuple(a[k].tolist()) if k in a else ()  # noqa: E731
    return Trajectory(a["time"], a["qpos"], a["qvel"], psi, tup("body_names"),
                      tup("dano_names"), tup("qpos_adr"), tup("dof_adr"), tup("pair_names"), meta)
