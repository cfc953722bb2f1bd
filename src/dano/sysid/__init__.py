"""System identification of contact parameters and mass scale from observed
trajectories (paper §V-A, Eq. 13)."""

from .problem import FitParameter, Observation, SysIdProblem, Weights, finite_difference_velocity, quat_log_error
from .solve import SysIdResult, identify

__all__ = ["FitParameter", "Observation", "SysIdProblem", "SysIdResult", "Weights", "finite_difference_velocity",
           "identify", "quat_log_error"]
