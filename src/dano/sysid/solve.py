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
    scan: dict | None = None

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
            "scan": self.scan,
        }


def scan_points(lower: np.ndarray, upper: np.ndarray, scan: int, seed: int = 0) -> np.ndarray:
    """Points of the coarse global scan over the box [lower, upper] (n,): a grid of ``scan``
    values per axis for n ≤ 2, else scrambled Sobol points (seeded), as many as the smallest
    power of two ≥ ``scan``² (Sobol balance needs a power of two). (K, n)."""
    from scipy.stats import qmc

    n = len(lower)
    if n <= 2:
        axes = [np.linspace(lower[i], upper[i], scan) for i in range(n)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, n)
    m = int(np.ceil(np.log2(scan * scan)))
    unit = qmc.Sobol(d=n, scramble=True, seed=np.random.default_rng(seed)).random_base2(m)
    return lower + unit * (upper - lower)


def scan_costs(problem: SysIdProblem, points: np.ndarray, batch: int = 16, residual_function=None) -> np.ndarray:
    """Cost ½‖r‖² at each row of ``points`` (K, n_global) (nuisance parameters at their
    initial values), evaluated ``batch`` points at a time through one vmapped, compiled
    residual (``residual_function``: the problem's, built once by the caller, or built
    here); non-finite costs (diverging rollouts) are returned as inf. Returns (K,)."""
    fun = residual_function or problem.residual_function()
    x0 = problem.initial()
    n = points.shape[1]
    cost = jax.jit(jax.vmap(lambda th: 0.5 * jnp.sum(fun(th) ** 2)))
    out = []
    for start in range(0, len(points), batch):
        chunk = points[start : start + batch]
        thetas = np.repeat(x0[None], batch, axis=0)
        thetas[: len(chunk), :n] = chunk
        thetas[len(chunk) :, :n] = chunk[-1]  # pad the last chunk: one compiled shape
        out.append(np.asarray(cost(jnp.asarray(thetas)))[: len(chunk)])
    c = np.concatenate(out)
    return np.where(np.isfinite(c), c, np.inf)


def _profiles(labels, points: np.ndarray, costs: np.ndarray, bins: int) -> dict:
    """Cost profile along each parameter: the lowest cost seen per value (grid) or bin."""
    prof = {}
    for i, lab in enumerate(labels):
        x = points[:, i]
        values = np.unique(x)
        if len(values) > bins:
            edges = np.linspace(x.min(), x.max(), bins + 1)
            idx = np.clip(np.digitize(x, edges) - 1, 0, bins - 1)
            values = 0.5 * (edges[:-1] + edges[1:])
            best = [float(costs[idx == b].min()) if np.any(idx == b) else None for b in range(bins)]
        else:
            best = [float(costs[x == v].min()) for v in values]
        prof[lab] = {"values": [float(v) for v in values],
                     "cost": [None if c is None or not np.isfinite(c) else c for c in best]}
    return prof


def identify(problem: SysIdProblem, *, jacobian: str = "ad", max_iterations: int = 50,
             xtol: float = 1e-8, ftol: float = 1e-8, gtol: float = 1e-8,
             horizons: tuple[float, ...] = (), scan: int = 0, starts: int = 3) -> SysIdResult:
    """Identify the problem's parameters; returns a :class:`SysIdResult`.

    scan: global start (0: off). Before the local solver, the cost is evaluated on a coarse
    scan of the global parameters' bounds (:func:`scan_points`: ``scan`` values per axis for
    one or two parameters, Sobol points beyond: the next power of two ≥ ``scan``²), in vmapped batches; the local
    solver then starts from the ``starts`` best points (and the given initial guess) and the
    lowest final cost wins. Without ``horizons`` the scan and every start share one traced
    residual and Jacobian (compiled once each). The result's ``scan`` holds the points, their costs, the starts
    and the cost profile along each parameter. Needs finite bounds on the global parameters.

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
    for h in horizons:
        if not 0 < h < 1:
            raise DanoError(f"horizons must be fractions in (0, 1), got {h}")
    if scan:
        return _identify_from_scan(problem, scan, starts, jacobian=jacobian, max_iterations=max_iterations,
                                   xtol=xtol, ftol=ftol, gtol=gtol, horizons=horizons)
    if horizons:
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
    return _local_solve(problem, _compile(problem), problem.initial(), jacobian=jacobian,
                        max_iterations=max_iterations, xtol=xtol, ftol=ftol, gtol=gtol)


def _compile(problem: SysIdProblem):
    """(residual function, its jit, the jit of its forward-mode Jacobian): one trace of the
    problem, shared by every local solve from another starting point."""
    r_fn = problem.residual_function()
    return r_fn, jax.jit(r_fn), jax.jit(jax.jacfwd(r_fn))  # the Jacobian compiles only when used


def _local_solve(problem: SysIdProblem, compiled, x0: np.ndarray, *, jacobian: str, max_iterations: int,
                 xtol: float, ftol: float, gtol: float, fitted: bool = True) -> SysIdResult:
    """Bounded least squares from ``x0`` (n,) with the compiled residual and Jacobian."""
    _, fun, jac_fn = compiled
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
        fitted=problem.simulate(sol.x) if fitted else [],
    )


def _identify_from_scan(problem: SysIdProblem, scan: int, starts: int, **local) -> SysIdResult:
    n = len(problem.parameters)
    if n == 0:
        raise DanoError("a global scan needs global parameters (only nuisance velocities are fitted)")
    if not 2 <= scan <= 64 or not 1 <= starts <= 16:
        raise DanoError(f"scan must be 2 to 64 points per axis and starts 1 to 16, got {scan} and {starts}")
    lo = np.array([p.lower for p in problem.parameters])
    hi = np.array([p.upper for p in problem.parameters])
    if not np.all(np.isfinite(hi)):
        raise DanoError("a global scan needs finite upper bounds on every parameter (set 'upper')")
    compiled = _compile(problem)
    t0 = time.perf_counter()
    points = scan_points(lo, hi, scan)
    costs = scan_costs(problem, points, residual_function=compiled[0])
    scan_time = time.perf_counter() - t0
    order = [int(i) for i in np.argsort(costs) if np.isfinite(costs[i])][:starts]
    if not order:
        raise DanoError("every point of the global scan gives a diverging simulation; check the bounds")
    candidates = [problem.initial()[:n]] + [points[i] for i in order]
    opts = {k: v for k, v in local.items() if k != "horizons"}
    results, kept = [], []
    for x in candidates:
        try:
            if local["horizons"]:  # continuation: truncated problems, compiled per start
                results.append(identify(problem.with_initial(x), **local))
            else:  # one compiled residual and Jacobian for every start
                x0 = np.concatenate([np.clip(x, lo, hi), problem.initial()[n:]])
                results.append(_local_solve(problem, compiled, x0, fitted=False, **opts))
            kept.append(x)
        except DanoError:  # a start whose rollout is non-finite (e.g. the given guess): skipped
            continue
    if not results:
        raise DanoError("no start of the global scan gives finite residuals")
    candidates = kept
    best = min(results, key=lambda r: r.final_cost)
    if not best.fitted:
        best.fitted = problem.simulate(best.estimates)
    best.initial = problem.initial()
    best.wall_time_s = sum(r.wall_time_s for r in results) + scan_time
    best.nfev = sum(r.nfev for r in results) + len(points)
    best.njev = sum(r.njev for r in results)
    best.scan = {
        "points": points.tolist(),
        "cost": [None if not np.isfinite(c) else float(c) for c in costs],
        "starts": [np.asarray(x).tolist() for x in candidates],
        "start_results": [{"estimates": r.estimates[:n].tolist(), "final_cost": r.final_cost} for r in results],
        "profile": _profiles([p.label for p in problem.parameters], points, costs, bins=max(scan, 8)),
        "wall_time_s": scan_time,
    }
    return best
