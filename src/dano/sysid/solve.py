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
    """Estimates with standard errors, the cost per iteration, wall time (compilation
    reported separately), the fit and what makes the uncertainty doubtful.

    labels (n,); estimates, standard_errors, initial (n,); standard errors come from
    σ²(JᵀJ)⁻¹, σ² = 2·cost/(m − n), and only where that formula holds: NaN for every
    parameter when the solver stopped before a convergence test was met, and for a
    parameter that sits at a bound (the others then from the Jacobian's remaining columns);
    cost_history: cost ½‖r‖² after each iteration (first: at the initial guess);
    rms_residual: √(2·cost/m); num_residuals m; nfev/njev: residual/Jacobian evaluations;
    jacobian: "ad" or "fd"; warnings: sentences saying why an error bar is missing or
    doubtful (not converged, at a bound, local minima that disagree, a fit poor for the
    stated noise); bootstrap: see :func:`bootstrap` (None unless asked for).
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
    warnings: list = field(default_factory=list)
    bootstrap: dict | None = None

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
            "warnings": list(self.warnings),
            "bootstrap": self.bootstrap,
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
             horizons: tuple[float, ...] = (), scan: int = 0, starts: int = 3,
             noise_rms: float | None = None, bootstrap_samples: int = 0, seed: int = 0) -> SysIdResult:
    """Identify the problem's parameters; returns a :class:`SysIdResult`.

    noise_rms: the rms residual that measurement noise alone would leave (residual units:
    m·√w for positions, rad·√w for rotations); when the fit's rms residual exceeds twice it,
    the result warns that the model does not explain the data to the noise level (its
    standard errors assume it does). bootstrap_samples: if > 0, also resample whole
    trajectories with replacement this many times (seeded by ``seed``) and refit each from
    the estimate (:func:`bootstrap`; needs at least two trajectories).

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
    if noise_rms is not None and not (np.isfinite(noise_rms) and noise_rms > 0):
        raise DanoError(f"noise_rms must be a positive number, got {noise_rms}")
    if bootstrap_samples < 0:
        raise DanoError(f"bootstrap_samples must be >= 0, got {bootstrap_samples}")
    result = _identify(problem, jacobian=jacobian, max_iterations=max_iterations, xtol=xtol, ftol=ftol, gtol=gtol,
                       horizons=horizons, scan=scan, starts=starts)
    if noise_rms is not None and result.rms_residual > 2 * noise_rms:
        result.warnings.append(
            f"rms residual {result.rms_residual:.3g} is {result.rms_residual / noise_rms:.1f}x the stated noise "
            f"{noise_rms:.3g}: the model does not explain the data to the noise level, and the standard errors "
            "(which assume it does) understate the uncertainty")
    if bootstrap_samples:
        result.bootstrap = bootstrap(problem, result.estimates, samples=bootstrap_samples, seed=seed,
                                     max_iterations=max_iterations)
    return result


def _identify(problem: SysIdProblem, *, jacobian: str, max_iterations: int, xtol: float, ftol: float, gtol: float,
              horizons: tuple[float, ...], scan: int, starts: int) -> SysIdResult:
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
            r = _identify(current.truncated(h), jacobian=jacobian, max_iterations=max_iterations, xtol=xtol,
                          ftol=ftol, gtol=gtol, horizons=(), scan=0, starts=starts)
            stages.append(r)
            current = problem.with_initial(r.estimates[: len(problem.parameters)])
        final = _identify(current, jacobian=jacobian, max_iterations=max_iterations, xtol=xtol, ftol=ftol,
                          gtol=gtol, horizons=(), scan=0, starts=starts)
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
    problem, kept on it (freed with it) and shared by every local solve from another
    starting point, by the problems :meth:`~SysIdProblem.with_initial` derives from it
    (continuation stages, :func:`cramer_rao` after a fit) and by the bootstrap's refits."""
    if "residual" not in problem._cache:
        r_fn = problem.residual_function()
        problem._cache["residual"] = (r_fn, jax.jit(r_fn), jax.jit(jax.jacfwd(r_fn)))  # Jacobian: compiled when used
    return problem._cache["residual"]


def _finite(a, fill: float) -> np.ndarray:
    """``a`` as a NumPy array with non-finite entries replaced by ``fill``."""
    a = np.asarray(a)
    return np.where(np.isfinite(a), a, fill)


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
        return _finite(fun(jnp.asarray(x)), 1e6)  # keep the solver away from diverging rollouts

    def jac(x):
        return _finite(jac_fn(jnp.asarray(x)), 0.0)  # rows of diverging rollouts carry no slope

    def callback(intermediate_result):
        history.append(float(intermediate_result.cost))

    t0 = time.perf_counter()
    sol = least_squares(f, x0, jac=jac if jacobian == "ad" else "2-point", bounds=(lo, hi), method="trf",
                        x_scale="jac", max_nfev=max_iterations, xtol=xtol,
                        ftol=ftol, gtol=gtol, callback=callback)
    wall = time.perf_counter() - t0
    m = len(sol.fun)
    se, notes = _standard_errors(problem, sol, max_iterations)
    return SysIdResult(
        labels=problem.labels, estimates=np.asarray(sol.x), standard_errors=se, initial=x0,
        cost_history=history, final_cost=float(sol.cost), rms_residual=float(np.sqrt(2 * sol.cost / m)),
        num_residuals=m, nfev=int(sol.nfev), njev=int(sol.njev or 0), wall_time_s=wall,
        compile_time_s=compile_time, success=bool(sol.success), message=str(sol.message), jacobian=jacobian,
        fitted=problem.simulate(sol.x) if fitted else [], warnings=notes,
    )


def at_bound(problem: SysIdProblem, x: np.ndarray) -> list[tuple[int, str]]:
    """Global parameters of ``x`` that sit on a bound (within 1e-6 of the bounds' span, or
    of max(1, |initial|) for a half-open range): [(index, "lower" | "upper")]."""
    out = []
    for i, p in enumerate(problem.parameters):
        span = p.upper - p.lower if np.isfinite(p.upper) else max(1.0, abs(p.initial))
        for side, b in (("lower", p.lower), ("upper", p.upper)):
            if np.isfinite(b) and abs(x[i] - b) <= 1e-6 * span:
                out.append((i, side))
    return out


def _standard_errors(problem: SysIdProblem, sol, max_iterations: int) -> tuple[np.ndarray, list[str]]:
    """Standard errors from σ²(JᵀJ)⁻¹ (n,) and the warnings that go with them: none when the
    solver did not meet a convergence test; none for a parameter at a bound, the others from
    the Jacobian without its column (the fit conditional on the bound)."""
    m, n = sol.fun.shape[0], sol.x.shape[0]
    se = np.full(n, np.nan)
    if sol.status <= 0:
        return se, [f"the solver stopped at its evaluation limit ({max_iterations}) before a convergence test was "
                    "met: no standard errors (not a converged minimum)"]
    notes, free = [], np.ones(n, dtype=bool)
    for i, side in at_bound(problem, sol.x):
        free[i] = False
        p = problem.parameters[i]
        notes.append(f"{p.label} = {sol.x[i]:.6g} sits at its {side} bound: no standard error (the cost may keep "
                     "falling beyond it; widen the bound if that is physical)")
    J = sol.jac[:, free]  # AD, or SciPy's finite differences, at the solution
    sigma2 = 2 * sol.cost / max(m - int(free.sum()), 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
        se[free] = np.sqrt(np.clip(np.diag(cov), 0, None))
    except np.linalg.LinAlgError:
        notes.append("JᵀJ is singular: the data do not determine every parameter; no standard errors")
    return se, notes


def cramer_rao(problem: SysIdProblem, theta, noise) -> np.ndarray:
    """The Cramér–Rao bound at θ: the smallest covariance (n, n) of θ that any unbiased
    estimator reaches from data like the problem's when its residuals carry independent
    Gaussian noise of standard deviation ``noise`` ((m,) or a scalar, residual units: e.g.
    :meth:`SysIdProblem.residual_noise`), (Jᵀ diag(noise⁻²) J)⁻¹ with the forward-mode
    Jacobian J at θ (the inverse Fisher information). Unlike a fit's standard errors it needs
    no fit, so it says in advance what data can determine (at the truth, for synthetic data).
    It assumes the residuals' noise independent; where an observed start is averaged from
    frames that are also residuals, or a start's error is not among the fitted nuisance
    parameters, it is an approximation.
    Raises DanoError if the scene is not float64, θ or the noise has the wrong size or is not
    finite and positive, the Jacobian is not finite at θ, or the information matrix is
    singular (a parameter the data cannot determine)."""
    if problem.scene.dtype != jnp.float64:
        raise DanoError(f"the Cramér–Rao bound needs a float64 scene, got {problem.scene.dtype}: call "
                        "dano.enable_float64() before composing the scene")
    theta = np.asarray(theta, dtype=np.float64)
    if theta.shape != (problem.num_parameters,):
        raise DanoError(f"theta must hold {problem.num_parameters} values ({', '.join(problem.labels)}), "
                        f"got shape {theta.shape}")
    if not np.all(np.isfinite(theta)):
        bad = [lab for lab, v in zip(problem.labels, theta) if not np.isfinite(v)]
        raise DanoError(f"theta must be finite; not finite: {', '.join(bad)}")
    noise = np.broadcast_to(np.asarray(noise, dtype=np.float64), (problem.num_residuals,)) \
        if np.ndim(noise) == 0 else np.asarray(noise, dtype=np.float64)
    if noise.shape != (problem.num_residuals,) or not np.all(np.isfinite(noise) & (noise > 0)):
        raise DanoError(f"noise must be {problem.num_residuals} positive standard deviations (or one), got shape "
                        f"{noise.shape}")
    _, _, jac_fn = _compile(problem)
    J = np.asarray(jac_fn(jnp.asarray(theta)))
    if not np.all(np.isfinite(J)):
        raise DanoError("the simulation's Jacobian is not finite at theta: no bound")
    Jw = J / noise[:, None]
    info = Jw.T @ Jw
    d = np.sqrt(np.diag(info))  # scaled to unit diagonal, so that the parameters' units do not matter
    if np.any(d == 0) or np.linalg.cond(info / np.outer(d, d)) > 1e12:
        unseen = [lab for lab, v in zip(problem.labels, d) if v == 0]
        raise DanoError("the Fisher information is singular: the data cannot determine every parameter"
                        + (f" (no effect at all: {', '.join(unseen)})" if unseen else ""))
    return np.linalg.inv(info / np.outer(d, d)) / np.outer(d, d)


def _identify_from_scan(problem: SysIdProblem, scan: int, starts: int, **local) -> SysIdResult:
    n = len(problem.parameters)
    if n == 0:
        raise DanoError("a global scan needs global parameters (only per-segment nuisance offsets are fitted)")
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
                results.append(_identify(problem.with_initial(x), scan=0, starts=starts, **local))
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
    best.warnings = best.warnings + _disagreement(problem, best, results, float(np.min(costs)))
    return best


def _disagreement(problem: SysIdProblem, best: SysIdResult, results: list, scan_best: float) -> list[str]:
    """Warnings when the global search and the local fits disagree: another start ended within
    5 % of the best cost at estimates further than 3 standard errors (1e-3 of the bounds'
    span where there is none) from the best, i.e. local minima the standard errors do not
    cover; or the scan saw a lower cost than any local fit reached."""
    n = len(problem.parameters)
    span = np.array([p.upper - p.lower for p in problem.parameters])
    tol = np.where(np.isfinite(best.standard_errors[:n]), 3 * best.standard_errors[:n], 1e-3 * span)
    others = [r for r in results if r is not best and r.final_cost <= 1.05 * best.final_cost + 1e-12
              and np.any(np.abs(r.estimates[:n] - best.estimates[:n]) > tol)]
    notes = []
    if others:
        lo = np.min([r.estimates[:n] for r in others + [best]], axis=0)
        hi = np.max([r.estimates[:n] for r in others + [best]], axis=0)
        spread = ", ".join(f"{p.label} {a:.4g}..{b:.4g}" for p, a, b in zip(problem.parameters, lo, hi))
        notes.append(f"{len(others)} other start(s) ended within 5 % of the best cost at different estimates "
                     f"({spread}): local minima; the standard errors understate the uncertainty (see the "
                     "bootstrap or the scan's profile)")
    if scan_best < best.final_cost * (1 - 1e-9):
        notes.append(f"the scan saw a lower cost ({scan_best:.6g}) than every local fit reached "
                     f"({best.final_cost:.6g}): the local solver stopped early")
    return notes


def bootstrap(problem: SysIdProblem, estimates: np.ndarray, *, samples: int = 100, seed: int = 0,
              level: float = 0.95, max_iterations: int = 50) -> dict:
    """Bootstrap over trajectories: ``samples`` times, draw as many trajectories as observed,
    with replacement (seeded), and refit from ``estimates`` (n,) by the bounded least-squares
    solver; a trajectory drawn k times weighs k (its residuals scaled by √k), so one compiled
    residual and Jacobian serve every draw. Trajectories are the independent units: noise
    that is shared within a trajectory (its initial pose, its tracking bias) makes σ²(JᵀJ)⁻¹
    too small, the spread over resampled trajectories does not.

    Returns {"samples", "seed", "level", "trajectories" (n), "labels" (the global parameters,
    and the ground's when fitted), "std" (the refits' standard deviation × √(n/(n−1)), the
    usual small-sample correction), "lower"/"upper" (estimate ∓ t_{n−1}·std at ``level``,
    clipped to the bounds: percentile intervals of a bootstrap over few trajectories are too
    narrow),
    "percentile_lower"/"percentile_upper", "estimates" (refits, k), "failed" (draws whose refit
    gave a non-finite result, left out)}. Raises DanoError for fewer than two trajectories,
    fewer than two samples, a level outside (0, 1), or fewer than two finite refits."""
    n_obs = len(problem.observations)
    if n_obs < 2:
        raise DanoError("the bootstrap resamples whole trajectories: it needs at least two")
    if not 0 < level < 1 or samples < 2:
        raise DanoError(f"bootstrap needs samples >= 2 and a level in (0, 1), got {samples} and {level}")
    _, fun, jac_fn = _compile(problem)
    owner = problem.residual_observations()
    lo, hi = problem.bounds()
    n_ground = len(problem.ground_labels)
    keep = list(range(len(problem.parameters))) + list(range(problem.num_parameters - n_ground,
                                                               problem.num_parameters))
    x0 = np.clip(np.asarray(estimates, dtype=np.float64), lo, hi)
    rng = np.random.default_rng(seed)
    out, failed = [], 0
    for _ in range(samples):
        scale = np.sqrt(np.bincount(rng.integers(0, n_obs, n_obs), minlength=n_obs).astype(np.float64))[owner]
        sol = least_squares(lambda x: _finite(fun(jnp.asarray(x)), 1e6) * scale, x0,
                            jac=lambda x: _finite(jac_fn(jnp.asarray(x)), 0.0) * scale[:, None], bounds=(lo, hi),
                            method="trf", x_scale="jac", max_nfev=max_iterations)
        if np.all(np.isfinite(sol.x)) and np.isfinite(sol.cost):
            out.append(sol.x[keep])
        else:
            failed += 1
    est = np.array(out).reshape(len(out), len(keep))
    if len(out) < 2:
        raise DanoError(f"the bootstrap's refits failed ({failed} of {samples} non-finite)")
    from scipy.stats import t as student_t

    q = 100 * (1 - level) / 2
    std = est.std(axis=0, ddof=1) * np.sqrt(n_obs / (n_obs - 1))  # small-sample correction of a cluster bootstrap
    half = student_t.ppf(0.5 + level / 2, n_obs - 1) * std
    centre = np.asarray(estimates, dtype=np.float64)[keep]
    lo_k, hi_k = lo[keep], hi[keep]  # an interval beyond a bound says nothing more than the bound
    return {"samples": samples, "seed": seed, "level": level, "trajectories": n_obs,
            "labels": [problem.labels[i] for i in keep], "std": std.tolist(),
            "lower": np.maximum(centre - half, lo_k).tolist(), "upper": np.minimum(centre + half, hi_k).tolist(),
            "percentile_lower": np.percentile(est, q, axis=0).tolist(),
            "percentile_upper": np.percentile(est, 100 - q, axis=0).tolist(),
            "estimates": est.tolist(), "failed": failed}
