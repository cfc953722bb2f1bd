"""System identification of contact parameters, mass scale and the object's own dynamics
from observed trajectories (paper §V-A, Eq. 13)."""

from .problem import FitParameter, Observation, SysIdProblem, Weights, finite_difference_velocity, quat_log_error
from .solve import SysIdResult, identify
from .uncertainty import bootstrap, cramer_rao, observation_noise

__all__ = ["FitParameter", "Observation", "SysIdProblem", "SysIdResult", "Weights", "bootstrap",
           "cramer_rao", "finite_difference_velocity", "identify", "observation_noise", "quat_log_error"]
