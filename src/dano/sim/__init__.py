"""Scenes, the public step and differentiable rollouts on MuJoCo MJX with DANO contact.

``compose`` builds a :class:`Scene` (a pytree); ``step(scene, params, data) -> data`` is
the pure, jittable, vmappable, differentiable step on MJX ``Data``; ``rollout`` and
``rollout_arrays`` run it inside one ``jax.lax.scan``.
"""

from .._jax_setup import batched_compiler_options, check_xla_flags, rollout_compiler_options

check_xla_flags()  # warn once if JAX started without the CPU fusion-emitter fix

from ..trajectory import Trajectory, load_trajectory, save_trajectory
from .implicit import NewtonConfig, NewtonOptions
from .rollout import SimulationDiverged, rollout, rollout_arrays, scan_steps
from .scene import DanoObject, Scene, SimParams, compose
from .dynamics import State, StepInfo, make_data, overlaps, step, step_with_info

__all__ = ["DanoObject", "NewtonConfig", "NewtonOptions",
           "Scene", "SimParams", "SimulationDiverged", "State", "StepInfo",
           "Trajectory", "batched_compiler_options", "compose", "load_trajectory", "make_data", "overlaps", "rollout",
           "rollout_arrays", "rollout_compiler_options", "save_trajectory", "scan_steps", "step", "step_with_info"]
