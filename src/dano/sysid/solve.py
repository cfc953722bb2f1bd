"""Solving the identification problem: bounded Gauss–Newton / Levenberg–Marquardt.

We use :func:`scipy.optimize.least_squares` (trust-region reflective, the bounded
Gauss–Newton-type method of SciPy) with the Jacobian from forward-mode AD through
the simulator (``jax.jacfwd``: θ has few entries, residuals many). It is a well-kept
solver that handles bounds, scaling and convergence tests; ``mujoco.minimize`` has no
bounds-aware TRF and optimistix would add a dependency for the same algorithm.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares

from ..errors import DanoError
from .problem import SysIdProblem


@dataclass
class SysIdResult:
    """Estimates with standard errors (from σ²(JᵀJ)⁻¹ at the optimum, σ² = 2·cost/(m − n)),
    the cost per iteration, wall time (compilation reported separately) and the fit.

    labels (n,); estimates, standard_errors, initial (n,); cost_history: cost
    ½‖r‖² after each iteration (first: at the initial guess); rms_residual: √(2·cost/m);
    num_residuals m; nfev/njev: residual/Jacobian evaluations; jacobian: "ad" or "fd".
    """

    labels: list
    estimates: np.ndarray
    standard_errors: np.ndarray
    initial: np.ndarray
    cost_history: list
    final_cost: float
    rms_residual: float
    num_residuals: int
    nfev: int
    njev: int
    wall_time_s: float
    compile_time_s: float
    success: bool
    message: str
    jacobian: str
    fitted: list = field(default_factory=list, repr=False)
    stages: list = field(default_factory=list)

    def as_dict(self) -> dict:
        return {
            "parameters": {k: float(v) for k, v in zip(self.labels, self.estimates)},
            "standard_errors": {k: float(v) for k, v in zip(self.labels, self.standard_errors)},
            "initial": {k: float(v) for k, v in zip(self.labels, self.initial)},
            "cost_history": [float(c) for c in self.cost_history],
            "final_cost": self.final_cost,
            "rms_residual": self.rms_residual,
            "num_residuals": self.num_residuals,
            "nfev": self.nfev,
            "njev": self.njev,
            "wall_time_s": self.wall_time_s,
            "compile_time_s": self.compile_time_s,
            "success": self.success,
            "message": self.message,
            "jacobian": self.jacobian,
            "stages": self.stages,
        }


def identify(problem: SysIdProblem, *, jacobian: str = "ad", max_iterations: int = 50,
             xtol: float = 1e-8, ftol: float = 1e-8, gtol: float = 1e-8,
             horizons: tuple[float, ...] = ()) -> SysIdResult:
    """Identify the problem's parameters; returns a :class:`SysIdResult`.

    jacobian: "ad" (forward-mode AD, default) or "fd" (SciPy's 2-point finite
    differences, for comparison). max_iterations: the most residual evaluations per
    stage (SciPy's ``max_nfev``; the trust-region method makes about one per iteration).
    horizons: continuation over the trajectory length,
    e.g. (0.4,): first fit on the first 40 % of every trajectory, then on all of it from
    that estimate (contact-rich cost landscapes are much smoother over short horizons,
    so a distant initial guess still reaches the right basin). Raises DanoError if the
    scene is not float64 (identification compares in float64: call
    :func:`dano.enable_float64` before composing it) or the rollout produces non-finite
    residuals at the initial guess.
    """
    if problem.scene.dtype != jnp.float64:
        raise DanoError(f"identification needs a float64 scene, got {problem.scene.dtype}: call "
                        "dano.enable_float64() before composing the scene")
    if jacobian not in ("ad", "fd"):
        raise DanoError(f"jacobian must be 'ad' or 'fd', got {jacobian!r}")
    if horizons:
        for h in horizons:
            if not 0 < h < 1:
                raise DanoError(f"horizons must be fractions in (0, 1), got {h}")
        stages, current = [], problem
        for h in horizons:
            r = identify(current.truncated(h), jacobian=jacobian, max_iterations=max_iterations, xtol=xtol,
                         ftol=ftol, gtol=gtol)
            stages.append(r)
            current = problem.with_initial(r.estimates[: len(problem.parameters)])
        final = identify(current, jacobian=jacobian, max_iterations=max_iterations, xtol=xtol, ftol=ftol, gtol=gtol)
        final.initial = problem.initial()
        final.wall_time_s += sum(r.wall_time_s for r in stages)
        final.compile_time_s += sum(r.compile_time_s for r in stages)
        final.nfev += sum(r.nfev for r in stages)
        final.njev += sum(r.njev for r in stages)
        final.stages = [{"horizon": h, "estimates": r.estimates.tolist(), "cost_history": r.cost_history}
                        for h, r in zip(horizons, stages)]
        return final
    r_fn = problem.residual_function()
    fun = jax.jit(r_fn)
    jac_fn = jax.jit(jax.jacfwd(r_fn))  # compiled only when used (jacobian="ad")
    x0 = problem.initial()
    lo, hi = problem.bounds()

    t0 = time.perf_counter()
    r0 = np.asarray(fun(jnp.asarray(x0)))
    if jacobian == "ad":
        np.asarray(jac_fn(jnp.asarray(x0)))
    compile_time = time.perf_counter() - t0
    if not np.all(np.isfinite(r0)):
        raise DanoError("the simulation gives non-finite residuals at the initial guess; check the scene and data")

    history = [0.5 * float(r0 @ r0)]

    def f(x):
        r = np.asarray(fun(jnp.asarray(x)))
        return np.where(np.isfinite(r), r, 1e6)  # keep the solver away from diverging rollouts

    def jac(x):
        J = np.asarray(jac_fn(jnp.asarray(x)))
        return np.where(np.isfinite(J), J, 0.0)  # rows of diverging rollouts carry no slope

    def callback(intermediate_result):
        history.append(float(intermediate_result.cost))

    t0 = time.perf_counter()
    sol = least_squares(f, x0, jac=jac if jacobian == "ad" else "2-point", bounds=(lo, hi), method="trf",
                        x_scale="jac", max_nfev=max_iterations, xtol=xtol,
                        ftol=ftol, gtol=gtol, callback=callback)
    wall = time.perf_counter() - t0
    m, n = len(sol.fun), len(x0)
    J = sol.jac  # AD, or SciPy's finite differences, at the solution
    sigma2 = 2 * sol.cost / max(m - n, 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
        se = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        se = np.full(n, np.nan)
    return SysIdResult(
        labels=problem.labels, estimates=np.asarray(sol.x), standard_errors=se, initial=x0,
        cost_history=history, final_cost=float(sol.cost), rms_residual=float(np.sqrt(2 * sol.cost / m)),
        num_residuals=m, nfev=int(sol.nfev), njev=int(sol.njev or 0), wall_time_s=wall,
        compile_time_s=compile_time, success=bool(sol.success), message=str(sol.message), jacobian=jacobian,
        fitted=problem.simulate(sol.x),
    )
