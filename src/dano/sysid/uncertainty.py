"""What the data say about the estimate: cost profiles through it, intervals that survive rough
costs and model misfit, the measurement noise estimated from the observations, identifiability,
the bootstrap over trajectories and the Cramér–Rao bound.

Profile (1-D, per global parameter i): on a grid of values v_k around the estimate θ̂, the
other parameters (global and nuisance) are re-optimised by chord Gauss–Newton steps with the
Jacobian J at θ̂ (θ_o ← θ_o − J_o⁺ r(θ)), at most three by default (fewer once a step gains
nothing), every step's residual
evaluated exactly and vmapped over the grid; each grid value keeps the lowest cost it reached.
So a profile point's cost is the cost at a real parameter vector (an upper bound of the true
profile), which the identification uses to verify its estimate.

Intervals at level 1 − a (default 95 %):
* profile likelihood: {v : C(v) ≤ C_min + ½·χ²₁(1 − a)·σ̂²·κ}, σ̂² = 2·C/(m − n) the noise
  variance from the residuals and κ = (1 + ρ)/(1 − ρ) ≥ 1 the variance inflation of residuals
  correlated in time (ρ: their lag-1 autocorrelation, pooled over every residual series): a
  model that misfits leaves smooth, correlated residuals that carry less information than
  their number says. The hull of all grid values under the threshold (ripples do not cut it).
* bootstrap over trajectories (from 4 trajectories up): each resample's estimate is the
  minimum over the grid of the resampled sum of per-trajectory profile costs (refined by a
  parabola), so a rough cost cannot stop it on a ripple; interval θ̂ ± t_{n−1}·s with the
  resamples' standard deviation s × √(n/(n−1)).
The reported interval is the hull of both (the more cautious).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable, NamedTuple

import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares
from scipy.special import chdtri, stdtrit  # (the quantiles without importing scipy.stats with this module)

from ..errors import DanoError
from ..pose import quat_error
from .problem import SysIdProblem, is_jittered

#: trajectories from which the bootstrap over trajectories is part of the default interval
BOOTSTRAP_MIN_TRAJECTORIES = 4


def finite(a, fill: float) -> np.ndarray:
    """``a`` as a NumPy array with non-finite entries replaced by ``fill``."""
    a = np.asarray(a)
    return np.where(np.isfinite(a), a, fill)


#: the largest residual magnitude the solvers see [residual units]: a non-finite entry counts
#: as this, a larger one is cut to it (a diverging rollout; its square stays finite)
RESIDUAL_CAP = 1e6


def bounded_residuals(r) -> np.ndarray:
    """Residuals ``r`` (..., m) with non-finite entries as :data:`RESIDUAL_CAP` and the others
    clipped to ±RESIDUAL_CAP: a cost ½‖r‖² the solvers can compare without overflow."""
    return np.clip(finite(r, RESIDUAL_CAP), -RESIDUAL_CAP, RESIDUAL_CAP)


#: from this many parameters (θ's entries, nuisance included) the local solvers see the residual
#: compressed block by block (:meth:`~dano.sysid.problem.JacobianBlocks.compressed`): a
#: trust-region SVD of K·n² instead of m·n², which is most of a solve from a few hundred
#: parameters on; below it the rows as they are. The Gauss–Newton model is the same, but its
#: rounding is not, and on a jagged cost (impacts, a model that misfits) SciPy's iterates carry
#: a rounding difference forward and grow it, as another thread count does: on the real cube
#: tosses (n = 4, compression forced) the costs parted from 1e-16 to 1e-4 in 13 iterations and
#: the solves ended 0.35 % apart. So smaller problems, whose SVD costs little, keep their rows
#: and their results
COMPRESS_MIN_PARAMETERS = 256


class LeastSquaresFunctions(NamedTuple):
    """What :func:`scipy.optimize.least_squares` takes, and the residual behind it.

    fun: x (n,) -> the residual the solver sees (bounded: :func:`bounded_residuals`, scaled
    per row), compressed (``compress``) to (K + 1,); jac: x -> its Jacobian, (m, n) or (K + 1,
    n) (non-finite entries 0), or None (SciPy's finite differences); raw: x -> (m,) the
    residual as computed (non-finite entries kept, to check a start); full: x -> ((m,), (m,
    n)) the solver's residual and Jacobian uncompressed (for standard errors and profiles
    after a compressed solve); compress: whether fun and jac are compressed."""

    fun: Callable
    jac: Callable | None
    raw: Callable
    full: Callable
    compress: bool


def least_squares_functions(problem: SysIdProblem, scale: np.ndarray | None = None, jacobian: bool = True,
                            compress: bool | None = None) -> LeastSquaresFunctions:
    """The residual and its Jacobian for :func:`scipy.optimize.least_squares`
    (:class:`LeastSquaresFunctions`), optionally scaled per residual (``scale`` (m,)); residual
    and Jacobian come from one compiled evaluation, the last one remembered (the solver asks
    for the Jacobian where it just evaluated). ``jacobian=False``: residuals only (for
    SciPy's finite differences). ``compress`` None: from :data:`COMPRESS_MIN_PARAMETERS`
    parameters on, with the Jacobian."""
    compress = jacobian and (problem.num_parameters >= COMPRESS_MIN_PARAMETERS if compress is None else compress)
    sc = 1.0 if scale is None else np.asarray(scale, dtype=np.float64)
    last: dict = {}

    def dense(blocks):  # the (m, n) Jacobian the solver's rows have
        J = finite(blocks.dense(), 0.0)
        return J if scale is None else J * sc[:, None]

    def both(x):
        x = np.asarray(x, dtype=np.float64)
        if "x" not in last or not np.array_equal(last["x"], x):
            if jacobian:
                blocks = problem.jacobian_blocks(x)
                raw, r = blocks.residuals, bounded_residuals(blocks.residuals) * sc
                fun, J = blocks.compressed(r, scale) if compress else (r, dense(blocks))
            else:
                raw = problem.residuals_only(x)
                blocks, r, J = None, bounded_residuals(raw) * sc, None
                fun = r
            last.clear()
            last.update(x=x.copy(), fun=fun, J=J, raw=raw, r=r, blocks=blocks)
        return last

    def full(x):
        got = both(x)
        return got["r"], (dense(got["blocks"]) if compress else got["J"])

    return LeastSquaresFunctions(lambda x: both(x)["fun"], (lambda x: both(x)["J"]) if jacobian else None,
                                 lambda x: both(x)["raw"], full, compress)


# ------------------------------------------------------------------ noise from the observations
def noise_of_observations(observations) -> dict:
    """The measurement noise of the observations, estimated from the observations alone (no
    model): third differences of positions (per axis x y z, world frame [m]), of the body-frame
    rotation increments log(q_t⁻¹ q_{t+1}) (their second differences, i.e. third differences
    of the angle [deg], reported as the rms rotation angle: √3 × the per-axis value, as
    :meth:`SysIdProblem.residual_noise` takes it) and of joint positions; the median over
    frames of all trajectories (robust to impacts and stops), within each run of consecutive
    frames (:meth:`~dano.sysid.Observation.runs`); where time stamps jitter, divided
    differences at the frames' own times, scaled to the frame interval (:func:`_differences`,
    so that the motion between uneven frames does not count as noise). Returns {"position_m" (3,),
    "rotation_deg", "joints", "method"}; a level the observations are too short for (fewer
    than 5 third differences) or that they do not observe is None."""
    pos, rot, joints = [], [], []
    for o in observations:
        jittered = is_jittered(o)
        for first, n in o.runs():  # (differences across missing frames would not be noise)
            if n < 4:
                continue
            t = np.asarray(o.time, dtype=np.float64)[first:first + n] if jittered else None
            for p in o.poses.values():
                p = np.asarray(p, dtype=np.float64)[first:first + n]
                pos.append(_differences(p[:, :3], 3, t, o.frame_dt))
                inc = quat_error(p[:-1, 3:], p[1:, 3:])
                if jittered:  # increments per frame interval, at the intervals' midpoints
                    inc, t_inc = inc * (o.frame_dt / np.diff(t))[:, None], 0.5 * (t[1:] + t[:-1])
                rot.append(_differences(inc, 2, t_inc if jittered else None, o.frame_dt))
            for v in o.joints.values():
                v = np.asarray(v, dtype=np.float64)[first:first + n]
                joints.append(_differences(v[:, None], 3, t, o.frame_dt)[:, 0])

    def level(ds, cols):
        if not ds or sum(len(d) for d in ds) < 5:
            return np.full(cols, np.nan)
        d = np.concatenate([np.reshape(x, (len(x), -1)) for x in ds])
        return np.median(np.abs(d), axis=0) / 0.6745 / np.sqrt(20.0)

    position = level(pos, 3)
    rot_axis = level(rot, 3)
    joint = level(joints, 1)
    return {"position_m": [float(v) for v in position] if np.all(np.isfinite(position)) else None,
            "rotation_deg": float(np.degrees(np.sqrt(np.sum(rot_axis**2)))) if np.all(np.isfinite(rot_axis)) else None,
            "joints": float(joint[0]) if np.isfinite(joint[0]) else None,
            "method": "third differences of the observed poses (positions, rotation increments, joints), median "
                      "absolute value / 0.6745 / sqrt(20), pooled over frames and trajectories"}


def _differences(x: np.ndarray, order: int, t: np.ndarray | None, step: float) -> np.ndarray:
    """The ``order``-th differences of x (n, k) along its rows; with times ``t`` (n,) [s] (time
    stamps that jitter) the divided differences scaled to equal spacing ``step``: order! ·
    step^order · x[t_i, ..., t_{i+order}], which are the plain differences where the times
    are ``step`` apart."""
    if t is None:
        return np.diff(x, n=order, axis=0)
    d = np.asarray(x, dtype=np.float64)
    for k in range(1, order + 1):
        d = np.diff(d, axis=0) / (t[k:] - t[:-k])[:, None]
    return d * (math.factorial(order) * step**order)


def observation_noise(problem: SysIdProblem) -> dict:
    """:func:`noise_of_observations` of ``problem``'s observations."""
    return noise_of_observations(problem.observations)


def expected_rms(problem: SysIdProblem, noise: dict) -> float | None:
    """The rms residual that the estimated measurement noise alone would leave (residual
    units), or None where it cannot be estimated."""
    pos = np.asarray(noise["position_m"], dtype=np.float64)
    rot = noise["rotation_deg"] if noise["rotation_deg"] is not None else 0.0
    joints = noise["joints"] if noise["joints"] is not None else 0.0
    if not np.all(np.isfinite(pos)):
        return None
    tiny = 1e-15  # noise-free data: a floor, so that residual_noise accepts the levels
    sd = problem.residual_noise(np.maximum(pos, tiny), max(rot, tiny), max(joints, tiny))
    return float(np.sqrt(np.mean(sd**2)))


def residual_autocorrelation(problem: SysIdProblem, r: np.ndarray) -> float:
    """Lag-1 autocorrelation of the residuals r (m,) in time, pooled over every residual series
    (one component of one block of one segment), in [0, 0.99] (negative values clipped to 0)."""
    num = den = 0.0
    for idx in problem.residual_series():
        x = r[idx]
        num += float(np.sum(x[1:] * x[:-1]))
        den += float(np.sum(x * x))
    return float(np.clip(num / den, 0.0, 0.99)) if den > 0 else 0.0


# ------------------------------------------------------------------ profiles
@dataclass(frozen=True)
class Profile:
    """A profile of the cost along global parameter ``index``: values (K,), costs (K,) (the
    lowest reached at each value), thetas (K, n) the parameter vectors where they were
    reached, per_trajectory (K, trajectories) those costs split by trajectory, failed (K,)
    int the failed steps of their rollouts (:meth:`~dano.sysid.SysIdProblem.failed_steps`)."""

    index: int
    values: np.ndarray
    costs: np.ndarray
    thetas: np.ndarray
    per_trajectory: np.ndarray
    failed: np.ndarray


def profile(problem: SysIdProblem, theta: np.ndarray, jac: np.ndarray, index: int, lower: float, upper: float,
            points: int = 32, steps: int = 3) -> Profile:
    """The cost profile along global parameter ``index`` over [lower, upper] (``points``
    values), the other parameters re-optimised by ``steps`` chord Gauss–Newton steps from θ
    (n,) with its Jacobian ``jac`` (m, n) (see the module's docstring). Parameters at a bound
    stay there; steps are clipped to the bounds."""
    lo, hi = problem.bounds()
    values = np.linspace(lower, upper, points)
    others = np.array([j for j in range(len(theta)) if j != index])
    J = finite(jac, 0.0)[:, others] if len(others) else np.zeros((len(jac), 0))
    pinv = np.linalg.pinv(J) if len(others) else np.zeros((0, len(jac)))
    thetas = np.repeat(np.asarray(theta, dtype=np.float64)[None], points, axis=0)
    thetas[:, index] = values
    owner = problem.residual_observations()
    best_cost = np.full(points, np.inf)
    best_theta = thetas.copy()
    best_res, best_failed = None, np.zeros(points, dtype=int)
    for step in range(steps + 1):
        R, failed = problem.batch_residuals(thetas, failures=True)
        R = bounded_residuals(R)  # (a wild chord step's: capped)
        cost = 0.5 * np.sum(R**2, axis=1)
        gain = np.max(np.where(np.isfinite(best_cost), best_cost - cost, np.inf))
        better = cost < best_cost
        if best_res is None:
            best_res = np.zeros_like(R)
        best_cost[better], best_theta[better], best_res[better] = cost[better], thetas[better], R[better]
        best_failed[better] = failed.sum(axis=1)[better]
        if step == steps or not len(others) or gain <= 1e-9 * np.min(best_cost):
            break  # converged (nuisances nearly linear: one step is often enough)
        thetas[:, others] = np.clip(thetas[:, others] - R @ pinv.T, lo[others], hi[others])
    per_traj = np.stack([0.5 * np.bincount(owner, weights=row**2, minlength=len(problem.observations))
                         for row in best_res])
    return Profile(index, values, best_cost, best_theta, per_traj, best_failed)


def profile_interval(values: np.ndarray, costs: np.ndarray, threshold: float,
                     estimate: float | None = None) -> tuple[float, float, bool, bool]:
    """The hull of the values whose cost lies within ``threshold`` of the lowest, its ends
    interpolated linearly to the crossing, and of ``estimate`` (the estimate's value, when
    given); returns (lower, upper, reaches the first value, reaches the last). A grid that
    steps over a minimum narrower than its spacing (noise-free data) leaves only its nearest
    value within the threshold: without the estimate, an interval beside it. (The threshold
    stays relative to the grid's lowest cost, not the estimate's: a profile's other
    parameters are re-optimised by a few chord steps, which leave every grid cost a little
    high alike.)"""
    c = costs - np.min(costs)
    inside = np.flatnonzero(c <= threshold)
    a, b = int(inside[0]), int(inside[-1])

    def cross(i, j):  # between an outside point i and an inside point j
        if not np.isfinite(c[i]):
            return values[j]
        f = (c[i] - threshold) / (c[i] - c[j]) if c[i] != c[j] else 0.0
        return values[i] + (values[j] - values[i]) * f

    lower = values[0] if a == 0 else cross(a - 1, a)
    upper = values[-1] if b == len(values) - 1 else cross(b + 1, b)
    if estimate is not None:
        lower, upper = min(lower, estimate), max(upper, estimate)
    return float(lower), float(upper), a == 0, b == len(values) - 1


def grid_minimum(values: np.ndarray, costs: np.ndarray) -> float:
    """The minimum of costs over values, refined by the parabola through it and its neighbours
    (kept within them)."""
    k = int(np.argmin(costs))
    if 0 < k < len(values) - 1:
        c0, c1, c2 = costs[k - 1], costs[k], costs[k + 1]
        den = c0 - 2 * c1 + c2
        if den > 0 and np.isfinite(den):
            h = values[k + 1] - values[k]
            return float(values[k] + np.clip(0.5 * h * (c0 - c2) / den, -h, h))
    return float(values[k])


def profile_bootstrap(prof: Profile, samples: int, rng: np.random.Generator) -> tuple[np.ndarray, int]:
    """Bootstrap over trajectories on a profile: each resample (trajectories drawn with
    replacement) takes the minimum over the grid of its weighted per-trajectory costs.
    Returns (estimates (samples,), how many fell on an end of the grid)."""
    n = prof.per_trajectory.shape[1]
    counts = np.stack([np.bincount(rng.integers(0, n, n), minlength=n) for _ in range(samples)])
    costs = counts @ prof.per_trajectory.T  # (samples, K)
    est = np.array([grid_minimum(prof.values, c) for c in costs])
    ends = int(np.sum(np.isin(np.argmin(costs, axis=1), (0, len(prof.values) - 1))))
    return est, ends


def count_local_minima(costs: np.ndarray, depth: float) -> int:
    """Interior local minima of a profile (K,) whose prominence exceeds ``depth`` (ripples that
    a local solver could stop in; non-finite costs count as the highest finite one), by
    :func:`scipy.signal.find_peaks` on −cost."""
    from scipy.signal import find_peaks

    c = np.asarray(costs, dtype=np.float64)
    c = np.where(np.isfinite(c), c, np.max(c[np.isfinite(c)], initial=0.0))
    return int(len(find_peaks(-c, prominence=depth)[0]))


def chi2_threshold(level: float) -> float:
    """½·χ²₁ quantile at ``level`` (in units of σ²: the cost rise that bounds the interval)."""
    return 0.5 * float(chdtri(1, 1.0 - level))  # (= scipy.stats.chi2.ppf(level, 1))


def t_quantile(level: float, dof: int) -> float:
    """Two-sided Student-t quantile for ``level`` with ``dof`` (at least 1) degrees of freedom."""
    return float(stdtrit(max(dof, 1), 0.5 + level / 2))  # (= scipy.stats.t.ppf)


# ------------------------------------------------------------------ refit bootstrap, Cramér–Rao
def bootstrap(problem: SysIdProblem, estimates: np.ndarray, *, samples: int = 100, seed: int = 0,
              level: float = 0.95, max_iterations: int = 50) -> dict:
    """Bootstrap over trajectories by refits: ``samples`` times, draw as many trajectories as
    observed, with replacement (seeded), and refit from ``estimates`` (n,) by the bounded
    least-squares solver; a trajectory drawn k times weighs k (its residuals scaled by √k), so
    one compiled residual and Jacobian serve every draw. Trajectories are the independent
    units: noise that is shared within a trajectory (its initial pose, its tracking bias)
    makes σ²(JᵀJ)⁻¹ too small, the spread over resampled trajectories does not. (The default
    interval of :func:`~dano.sysid.identify` resamples the profiles instead: no refits, and
    no local minima.)

    Returns {"samples", "seed", "level", "trajectories" (n), "labels" (the global parameters,
    and the ground's when fitted), "std" (the refits' standard deviation × √(n/(n−1)), the
    usual small-sample correction), "lower"/"upper" (estimate ∓ t_{n−1}·std at ``level``,
    clipped to the bounds: percentile intervals of a bootstrap over few trajectories are too
    narrow), "percentile_lower"/"percentile_upper", "estimates" (refits, k), "failed" (draws
    whose refit gave a non-finite result, left out), "unconverged" (draws whose refit was still
    at the evaluation limit after a second ``max_iterations`` from where the first stopped,
    left out: a refit stopped on its way from the estimate to its own minimum would narrow the
    spread)}. Raises DanoError for fewer than two trajectories, fewer than two samples, a level
    outside (0, 1), or fewer than two finite, converged refits."""
    n_obs = len(problem.observations)
    if n_obs < 2:
        raise DanoError("the bootstrap resamples whole trajectories: it needs at least two")
    if not 0 < level < 1 or samples < 2:
        raise DanoError(f"bootstrap needs samples >= 2 and a level in (0, 1), got {samples} and {level}")
    owner = problem.residual_observations()
    lo, hi = problem.bounds()
    n_ground = len(problem.ground_labels)
    keep = list(range(len(problem.parameters))) + list(range(problem.num_parameters - n_ground,
                                                               problem.num_parameters))
    x0 = np.clip(np.asarray(estimates, dtype=np.float64), lo, hi)
    rng = np.random.default_rng(seed)
    out, failed, unconverged = [], 0, 0
    for _ in range(samples):
        scale = np.sqrt(np.bincount(rng.integers(0, n_obs, n_obs), minlength=n_obs).astype(np.float64))[owner]
        f = least_squares_functions(problem, scale)
        fun, jac = f.fun, f.jac
        sol = least_squares(fun, x0, jac=jac, bounds=(lo, hi), method="trf", x_scale="jac", max_nfev=max_iterations)
        if sol.status == 0 and np.all(np.isfinite(sol.x)):  # at the evaluation limit: once more from there
            sol = least_squares(fun, np.clip(sol.x, lo, hi), jac=jac, bounds=(lo, hi), method="trf", x_scale="jac",
                                max_nfev=max_iterations)
        if not (np.all(np.isfinite(sol.x)) and np.isfinite(sol.cost)):
            failed += 1
        elif sol.status == 0:
            unconverged += 1
        else:
            out.append(sol.x[keep])
    est = np.array(out).reshape(len(out), len(keep))
    if len(out) < 2:
        raise DanoError(f"the bootstrap's refits failed: {failed} of {samples} non-finite, {unconverged} still at "
                        f"the evaluation limit ({max_iterations}, twice)")
    q = 100 * (1 - level) / 2
    std = est.std(axis=0, ddof=1) * np.sqrt(n_obs / (n_obs - 1))  # small-sample correction of a cluster bootstrap
    half = t_quantile(level, n_obs - 1) * std
    centre = np.asarray(estimates, dtype=np.float64)[keep]
    lo_k, hi_k = lo[keep], hi[keep]  # an interval beyond a bound says nothing more than the bound
    return {"samples": samples, "seed": seed, "level": level, "trajectories": n_obs,
            "labels": [problem.labels[i] for i in keep], "std": std.tolist(),
            "lower": np.maximum(centre - half, lo_k).tolist(), "upper": np.minimum(centre + half, hi_k).tolist(),
            "percentile_lower": np.percentile(est, q, axis=0).tolist(),
            "percentile_upper": np.percentile(est, 100 - q, axis=0).tolist(),
            "estimates": est.tolist(), "failed": failed, "unconverged": unconverged}


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
    J = problem.jacobian(theta)
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
