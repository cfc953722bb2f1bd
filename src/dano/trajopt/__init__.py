"""Trajectory optimisation through contact: constrained iLQR (augmented Lagrangian) on
:func:`dano.sim.step`, receding-horizon control, and the built-in tasks of ``dano trajopt``.

``Problem`` states the dynamics, costs and constraints; ``solve`` runs the solver;
``receding_horizon`` re-plans from measured states; ``tasks`` holds the paper's push.
"""

from .ilqr import LOG_KEYS, ILQRConfig, Multipliers, Options, Solution, rollout, solve
from .mpc import RecedingHorizonResult, receding_horizon
from .problem import Problem, mjx_dynamics, quadratic, quadratic_problem, scene_dynamics

__all__ = ["ILQRConfig", "LOG_KEYS", "Multipliers", "Options", "Problem", "RecedingHorizonResult", "Solution", "mjx_dynamics",
           "quadratic", "quadratic_problem", "receding_horizon", "rollout", "scene_dynamics", "solve"]
