"""Scenes and differentiable rollouts on MuJoCo MJX with DANO contact."""

from .._jax_setup import check_xla_flags

check_xla_flags()  # warn once if JAX started without the CPU fusion-emitter fix

from .scene import DanoObject, Scene, SimParams, compose
from .step import (SimulationDiverged, State, Trajectory, load_trajectory, rollout, rollout_arrays,
                   save_trajectory)

__all__ = ["DanoObject", "Scene", "SimParams", "SimulationDiverged", "State", "Trajectory", "compose",
           "load_trajectory", "rollout", "rollout_arrays", "save_trajectory"]
