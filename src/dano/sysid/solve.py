"""Solving the identification problem: a global scan, bounded Gauss–Newton / Levenberg–Marquardt
from its best points, and a verification of the answer by profiles through it.

We use :func:`scipy.optimize.least_squares` (trust-region reflective, the bounded
Gauss–Newton-type method of SciPy) with the Jacobian from forward-mode AD through
the simulator (``jax.jacfwd``: θ has few entries, residuals many). It is a well-kept
solver that handles bounds, scaling and convergence tests; ``mujoco.minimize`` has no
bounds-aware TRF and optimistix would add a dependency for the same algorithm.

By default (:func:`identify`): (1) the cost is evaluated on a scan of the global parameters'
bounds (a grid for one or two, Sobol points beyond); (2) the local solver starts from the best
scan points (moved off the bounds) and the given guess, and segments that the best answer
fits far worse than the others have their nuisance blocks re-scanned, the solve continued
from their lowest candidates (:func:`segment_restarts`); (3) the best answer is verified by a
profile through it along each global parameter (:mod:`dano.sysid.uncertainty`), finer than
its interval: if any point the tool evaluated has a lower cost, the local solver continues
from it, so the reported estimate never costs more than a point the tool saw; (4) the
interval, the measurement noise estimated from the observations, the misfit and the
identifiability of each parameter are reported, with warnings.
"""

from __future__ import annotations

import dataclasses
import re
import time
from dataclasses import dataclass, field
from typing import Sequence

import jax
import jax.numpy as jnp
import numpy as np
from scipy.optimize import least_squares

from ..errors import DanoError
from . import uncertainty as unc
from .._compiled import compile_seconds
from .._threads import in_background, or_error, side_by_side
from ..sim.implicit import DEFAULT_FAILURE_SUBSTEPS, MAX_TURN_CHANGE
from .problem import NEXT_FRAMES, NOISE_FLOOR, SysIdProblem, noisy_start_velocities, stray_start_velocities


@dataclass
class SysIdResult:
    """Estimates with their interval and standard errors, the cost per iteration, wall time
    (compilation reported separately), the fit and what makes the uncertainty doubtful.

    labels (n,); estimates, standard_errors, initial (n,); standard errors come from
    σ²(JᵀJ)⁻¹, σ² = 2·cost/(m − n), and only where that formula holds: NaN for every
    parameter when the solver stopped before a convergence test was met, for a parameter
    that sits at a bound (the others then from the Jacobian's remaining columns), and for a
    parameter whose cost is rough (the profile's curvature at the scale of the interval is
    not the local one); cost_history: cost ½‖r‖² after each iteration (first: at the initial
    guess); rms_residual: √(2·cost/m); num_residuals m; nfev/njev: residual/Jacobian
    evaluations; jacobian: "ad" or "fd"; warnings: sentences saying why an error bar is
    missing or doubtful (not converged, at a bound, local minima that disagree, a fit poor
    for the noise, a parameter the data do not determine); notes: choices made for the user
    (e.g. a contact term held neutral); bootstrap: the refit bootstrap when asked
    (:func:`~dano.sysid.uncertainty.bootstrap`); interval: the default interval per global
    parameter with its method (:func:`identify`); noise: the measurement noise estimated
    from the observations and the rms residual it alone would leave; identifiability: per
    global parameter "identified", "at bound", "flat", "one-sided" or "rough"; profiles: the cost profile
    through the estimate along each global parameter; verification: restarts from lower
    points the checks found; segment_scan: the re-scan of segments fitted far worse than the
    others (:func:`segment_restarts`), None where no segment was; failure_substeps: the
    substeps the rollouts took each step whose Newton solve failed in (1: single steps; more
    where :func:`identify` turned them on: rollouts that diverged or steps that failed near
    the answer, said in ``notes``); start_velocity: where the rollouts started (the problem's
    own, or "first frames" where :func:`identify` took them there: said in ``notes``). Simulate
    the answer with the problem it came from, ``problem.as_identified(result)``.
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
    interval: dict | None = None
    noise: dict | None = None
    identifiability: dict = field(default_factory=dict)
    profiles: dict | None = None
    verification: dict | None = None
    notes: list = field(default_factory=list)
    segment_scan: dict | None = None
    failure_substeps: int = 1
    start_velocity: str | None = None
    jacobian_matrix: np.ndarray | None = field(default=None, repr=False)

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
            "interval": self.interval,
            "noise_estimate": self.noise,
            "identifiability": self.identifiability,
            "profiles": self.profiles,
            "verification": self.verification,
            "segment_scan": self.segment_scan,
            "notes": list(self.notes),
            "failure_substeps": self.failure_substeps,
            "start_velocity": self.start_velocity,
        }


#: points of the default global scan per number of global parameters: a grid of 15 values for
#: one (with the initial guess, one vmapped batch of 16), 8 × 8 for two, 64 Sobol points beyond
#: (the budget is reported in ``scan["budget"]``)
DEFAULT_SCAN = {1: 15, 2: 8}
DEFAULT_SCAN_MORE = 8


def default_scan(n_global: int) -> int:
    """Points per axis of the default scan (:func:`scan_points`) for ``n_global`` parameters."""
    return DEFAULT_SCAN.get(n_global, DEFAULT_SCAN_MORE)


def scan_box(problem: SysIdProblem) -> tuple[np.ndarray, np.ndarray]:
    """The box the global scan covers: each global parameter's bounds; where a bound is
    infinite, [lower, lower + 4·(initial − lower)] (or a width of 1 when the guess is on the
    bound), and symmetric about the guess when both are infinite."""
    lo, hi = [], []
    for p in problem.parameters:
        a, b = p.lower, p.upper
        width = 4 * (p.initial - a) if np.isfinite(a) and p.initial > a else 1.0
        if not np.isfinite(a) and not np.isfinite(b):
            a, b = p.initial - max(abs(p.initial), 1.0), p.initial + max(abs(p.initial), 1.0)
        elif not np.isfinite(b):
            b = a + width
        elif not np.isfinite(a):
            a = b - (4 * (b - p.initial) if p.initial < b else 1.0)
        lo.append(a)
        hi.append(b)
    return np.array(lo, dtype=np.float64), np.array(hi, dtype=np.float64)


def scan_points(lower: np.ndarray, upper: np.ndarray, scan: int, seed: int = 0) -> np.ndarray:
    """Points of the coarse global scan over the box [lower, upper] (n,): a grid of ``scan``
    values per axis for n ≤ 2, else scrambled Sobol points (seeded), as many as the smallest
    power of two ≥ ``scan``² (Sobol balance needs a power of two). (K, n)."""
    n = len(lower)
    if n <= 2:
        axes = [np.linspace(lower[i], upper[i], scan) for i in range(n)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, n)
    from scipy.stats import qmc  # (scipy.stats: 0.25 s to import, only where Sobol points are needed)

    m = int(np.ceil(np.log2(scan * scan)))
    unit = qmc.Sobol(d=n, scramble=True, seed=np.random.default_rng(seed)).random_base2(m)
    return lower + unit * (upper - lower)


def scan_costs(problem: SysIdProblem, points: np.ndarray) -> np.ndarray:
    """Cost ½‖r‖² at each row of ``points`` (K, n_global) (nuisance parameters at their
    initial values), through the problem's vmapped, compiled residual
    (:meth:`SysIdProblem.batch_residuals`); non-finite costs (diverging rollouts) are returned
    as inf. Returns (K,)."""
    return _scan(problem, points)[0]


def _scan(problem: SysIdProblem, points: np.ndarray, failures: bool = False) -> tuple[np.ndarray, ...]:
    """(:func:`scan_costs`, (K, trajectories) bool: whether a trajectory's residuals at the
    point are non-finite or above :data:`DIVERGED_RESIDUAL`: its rollout diverged); with
    ``failures`` also (K, trajectories) int: its rollouts' failed steps
    (:meth:`~dano.sysid.SysIdProblem.failed_steps`)."""
    x0 = problem.initial()
    thetas = np.repeat(x0[None], len(points), axis=0)
    thetas[:, : points.shape[1]] = points
    r, failed_segments = problem.batch_residuals(thetas, failures=True)
    with np.errstate(over="ignore", invalid="ignore"):  # (a diverging rollout's cost: inf, said above)
        c = 0.5 * np.sum(r**2, axis=1)
        bad = ~np.isfinite(r) | (np.abs(r) > DIVERGED_RESIDUAL)
    obs = problem.residual_observations()
    diverged = np.zeros((len(points), len(problem.observations)), dtype=bool)
    for k in range(len(problem.observations)):
        diverged[:, k] = bad[:, obs == k].any(axis=1)
    out = (np.where(np.isfinite(c), c, np.inf), diverged)
    return out + (_per_trajectory(problem, failed_segments),) if failures else out


#: a weighted residual entry above this counts as a diverged rollout in the scan's report
#: (a trajectory thrown kilometres off: finite, yet no fit); the cost still counts it as it is
DIVERGED_RESIDUAL = 1e6


def _divergence_warning(problem: SysIdProblem, points: np.ndarray, diverged: np.ndarray) -> list[str]:
    """A warning where the rollouts of some trajectories diverged at some scan points: the
    identification then rests on the rest of the box, and the usual cause, a time step too
    coarse for the impacts, is the user's to fix. ``diverged``: :func:`_scan`'s (K, trajectories)."""
    at = diverged.any(axis=1)
    if not at.any():
        return []
    labels = [p.label for p in problem.parameters]
    shown = ", ".join("(" + ", ".join(f"{v:.3g}" for v in points[i]) + ")" for i in np.flatnonzero(at)[:4])
    which = np.flatnonzero(diverged.any(axis=0))
    names = [problem.observations[k].name or f"trajectory {k}" for k in which]
    return [f"the simulation diverged (non-finite or runaway residuals) at {int(at.sum())} of the {len(points)} "
            f"parameter points the scan evaluated (the initial guess among them), e.g. ({', '.join(labels)}) = {shown}{' …' if at.sum() > 4 else ''}, in {len(which)} of "
            f"{len(problem.observations)} trajectories ({', '.join(names[:5])}"
            f"{f' and {len(names) - 5} more' if len(names) > 5 else ''}): the identification rests on the rest of "
            "the box. A time step too coarse for the impacts is the usual cause: lower the scene's dt and raise "
            "[options].substeps to match (the frame interval is dt × substeps)"]


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


class _SingleStepsFail(Exception):
    """Raised where rollouts with single steps diverge or have failed steps at the points a
    local solve starts from (``summary``: what and where), caught by :func:`identify`, which
    identifies again with the failed steps' substeps."""

    def __init__(self, summary: str):
        super().__init__(summary)
        self.summary = summary


class _NonFiniteStart(DanoError):
    """Raised by a local solve whose residuals are non-finite at its start: skipped among a
    scan's starts; where the solve is the only one (no scan) and the problem takes single
    steps, :func:`identify` identifies again with the failed steps' substeps."""


def _per_trajectory(problem: SysIdProblem, per_segment: np.ndarray) -> np.ndarray:
    """(..., trajectories) sums of (..., segments) counts (e.g. failed steps): a trajectory's
    segments (windows, runs between missing frames) added."""
    out = np.zeros(per_segment.shape[:-1] + (len(problem.observations),), dtype=per_segment.dtype)
    for sid, seg in enumerate(problem.segments):
        out[..., seg.obs] += per_segment[..., sid]
    return out


def _failed_summary(failed: np.ndarray, where: str) -> str:
    """'had N failed steps ... in K of T trajectories <where>' from (T,) failed-step counts."""
    return (f"had {int(failed.sum())} failed steps (their Newton solve not converged, or a contact turning by more "
            f"than {MAX_TURN_CHANGE} rad in a step) in {int((failed > 0).sum())} of {len(failed)} trajectories "
            f"{where}")


def identify(problem: SysIdProblem, *, jacobian: str = "ad", max_iterations: int | None = None,
             xtol: float = 1e-8, ftol: float | None = None, gtol: float = 1e-8,
             horizons: tuple[float, ...] = (), scan: int | None = None, starts: int = 2,
             noise_rms: float | None = None, bootstrap_samples: int = 0, seed: int = 0,
             level: float = 0.95, profile_points: int | None = None) -> SysIdResult:
    """Identify the problem's parameters; returns a :class:`SysIdResult`.

    scan: global start: points per axis of a scan of the global parameters' bounds
    (:func:`scan_points`: a grid for one or two parameters, Sobol points beyond: the next
    power of two ≥ ``scan``²; a parameter without a finite bound is scanned over
    :func:`scan_box`), evaluated in vmapped batches; None (default): :func:`default_scan`
    (15 points for one parameter, 8 × 8 for two, 64 beyond); 0: off (local solve from the
    initial guess only). The local solver then starts from at most ``starts`` of the scan's
    points and the given guess, lowest cost first, each with no lower point near it (one
    start per basin the scan resolves: :func:`_basin_starts`; scan points moved off the
    bounds by 2 % of the box), and the lowest final cost wins. Where ``start_velocity="auto"``
    took the starts from the next frames (a first frame taken as off), the scan is evaluated
    once more with every rollout started from its first frames, and the problem started so
    (:meth:`~dano.sysid.SysIdProblem.started_from_first_frames`) is identified instead where
    that scan's lowest cost is lower (:func:`_first_frames_if_they_fit`; a note says so). Where the problem takes single
    steps (``SysIdProblem.failure_substeps`` 1, the default), the identification starts again
    with each step whose Newton solve fails taken in
    :data:`~dano.sim.implicit.DEFAULT_FAILURE_SUBSTEPS` substeps (a program of its own), and a
    note says why, where its rollouts diverge at a point a local solve starts from, or steps
    fail (:meth:`~dano.sysid.SysIdProblem.failed_steps`, AD Jacobians) at the scan's lowest
    point, at the initial guess without a scan, or at the answer, or where steps fail at
    points of the verification's profiles inside the interval and the substeps move their
    cost by more than the interval's threshold (:func:`_check_profiles`). Rollouts that
    diverge only at other scan points are named in a warning. (Without the verification a fit
    can still settle where no step fails while steps fail nearer the truth:
    ``SysIdProblem(failure_substeps=4)`` takes them always.)
    The result's ``scan`` holds the points, their costs, the starts and the cost profile along
    each parameter. A segment that the answer fits far worse than the median segment has its
    nuisance block re-scanned and the solve continued (:func:`segment_restarts`; the
    result's ``segment_scan``).

    profile_points: the verification and interval (:mod:`dano.sysid.uncertainty`): a profile
    through the estimate along each global parameter of this many points (default 32 for one
    or two global parameters, 16 beyond; 0: off, and no interval), refined until finer than
    the interval and widened until the interval lies inside it; whenever a point the tool
    evaluated (scan or profile) costs less than the estimate, the local solver continues from
    it. The interval at ``level`` is the hull of the profile-likelihood interval (noise from
    the residuals, inflated for residuals correlated in time) and, from 4 trajectories up, a
    bootstrap over trajectories on the profiles (seeded by ``seed``); the measurement noise is
    estimated from the observations themselves (third differences) and a fit well above it is
    warned about, as is a parameter whose profile is flat (not identifiable) or rough.

    noise_rms: the rms residual that measurement noise alone would leave (residual units:
    m·√w for positions, rad·√w for rotations), if known; when the fit's rms residual exceeds
    twice it, the result warns that the model does not explain the data to the noise level.
    bootstrap_samples: if > 0, also resample whole trajectories with replacement this many
    times and refit each from the estimate (:func:`~dano.sysid.uncertainty.bootstrap`; needs
    at least two trajectories).

    jacobian: "ad" (forward-mode AD, default) or "fd" (SciPy's 2-point finite
    differences, for comparison). xtol, ftol, gtol: SciPy's convergence tests; ftol None
    (default): :func:`statistical_ftol`, an iteration that lowers the cost by less than
    :data:`COST_TOLERANCE` of the residual variance ends the solve. max_iterations: the
    most residual evaluations per local solve (SciPy's ``max_nfev``; the trust-region method
    makes about one per iteration); default max(50, 10 × the parameters, nuisance included:
    the starts' velocities that ``fit_velocity="auto"`` adds converge more slowly, 85
    evaluations for 13 parameters).
    horizons: continuation over the trajectory length, e.g. (0.4,): first fit on the first
    40 % of every trajectory, then on all of it from that estimate (contact-rich cost
    landscapes are much smoother over short horizons). Raises DanoError if the scene is not
    float64 (identification compares in float64: call :func:`dano.enable_float64` before
    composing it), the rollout produces non-finite residuals at every start, or an option is
    out of range.
    """
    if noise_rms is not None and not (np.isfinite(noise_rms) and noise_rms > 0):
        raise DanoError(f"noise_rms must be a positive number, got {noise_rms}")
    if bootstrap_samples < 0:
        raise DanoError(f"bootstrap_samples must be >= 0, got {bootstrap_samples}")
    if not 0 < level < 1:
        raise DanoError(f"level must lie in (0, 1), got {level}")
    if problem.scene.dtype != jnp.float64:
        raise DanoError(f"identification needs a float64 scene, got {problem.scene.dtype}: call "
                        "dano.enable_float64() before composing the scene")
    if jacobian not in ("ad", "fd"):
        raise DanoError(f"jacobian must be 'ad' or 'fd', got {jacobian!r}")
    for h in horizons:
        if not 0 < h < 1:
            raise DanoError(f"horizons must be fractions in (0, 1), got {h}")
    if max_iterations is None:
        max_iterations = max(50, 10 * problem.num_parameters)
    if max_iterations < 1:
        raise DanoError(f"max_iterations must be >= 1, got {max_iterations}")
    n_global = len(problem.parameters)
    if profile_points is None:
        profile_points = 32 if n_global <= 2 else 16
    if profile_points and not 8 <= profile_points <= 256:
        raise DanoError(f"profile_points must be 0 (off) or 8 to 256, got {profile_points}")
    if scan is None:
        scan = default_scan(n_global) if n_global else 0
    if scan and (not 2 <= scan <= 64 or not 1 <= starts <= 16):
        raise DanoError(f"scan must be 2 to 64 points per axis and starts 1 to 16, got {scan} and {starts}")
    started = time.time()
    local = dict(jacobian=jacobian, max_iterations=max_iterations, xtol=xtol, ftol=ftol, gtol=gtol)

    def solve(problem: SysIdProblem, scanned=None) -> SysIdResult:
        result = _identify(problem, horizons=horizons, scan=scan, starts=starts, scanned=scanned, **local)
        result = segment_restarts(problem, result, level=level, **local)
        failed = problem.failed_steps(result.estimates) if problem.failure_substeps == 1 and jacobian == "ad" \
            else np.zeros(0, int)
        if failed.any():  # (steps that fail at the answer without diverging)
            raise _SingleStepsFail(_failed_summary(_per_trajectory(problem, failed), "at the estimate"))
        if profile_points and n_global:
            return _verify_and_assess(problem, result, profile_points, level, seed, local)
        result.noise = _noise_and_misfit(problem, result)
        return result

    problem, scanned = _first_frames_if_they_fit(problem, scan) if scan and n_global else (problem, None)
    retried = None
    try:
        result = solve(problem, scanned)
    except (_SingleStepsFail, _NonFiniteStart) as e:
        if problem.failure_substeps != 1:
            raise
        retried = e.summary if isinstance(e, _SingleStepsFail) else "diverged at the initial guess"
        problem = problem.with_failure_substeps(DEFAULT_FAILURE_SUBSTEPS)  # once: a program of its own
        result = solve(problem)
    result.notes = list(problem.notes) + result.notes
    if retried:
        result.notes.append(f"the rollouts {retried} with single steps: identified with each step whose Newton "
                            f"solve failed taken again in {DEFAULT_FAILURE_SUBSTEPS} substeps (docs/simulation.md, "
                            "'Substeps where a step fails')")
    result.failure_substeps, result.start_velocity = problem.failure_substeps, problem.start_velocity
    result.warnings = list(dict.fromkeys(result.warnings))  # each said once, in order
    if noise_rms is not None and result.rms_residual > 2 * noise_rms:
        result.warnings.append(
            f"rms residual {result.rms_residual:.3g} is {result.rms_residual / noise_rms:.1f}x the stated noise "
            f"{noise_rms:.3g}: the model does not explain the data to the noise level, and the standard errors "
            "(which assume it does) understate the uncertainty")
    if bootstrap_samples:
        result.bootstrap = unc.bootstrap(problem, result.estimates, samples=bootstrap_samples, seed=seed,
                                         max_iterations=max_iterations)
        left = result.bootstrap["failed"] + result.bootstrap["unconverged"]
        if left:
            result.warnings.append(
                f"{left} of {bootstrap_samples} bootstrap refits left out ({result.bootstrap['unconverged']} still at "
                f"the evaluation limit, {result.bootstrap['failed']} not finite): the bootstrap's interval is from "
                "the rest, and may be too narrow if the left-out draws were the far ones")
    if not result.fitted:  # (AD: from the Jacobian's program, already compiled; FD: a rollout of its own)
        result.fitted = problem.fitted(result.estimates) if jacobian == "ad" else problem.simulate(result.estimates)
    result.compile_time_s = compile_seconds(started)  # tracing, lowering and compiling (loads too), scan included
    return result


#: how the note of :func:`_first_frames_if_they_fit` begins
FIRST_FRAMES_FIT_NOTE = "start velocities: the first frames disagree with the parabola through the next"


def _first_frames_if_they_fit(problem: SysIdProblem, scan: int) -> tuple[SysIdProblem, tuple | None]:
    """(the problem, or, where ``start_velocity="auto"`` took its starts from the next frames
    (a first frame taken as off) and the scan's lowest cost is lower with each rollout started
    from its first three frames (the same points, nuisance offsets 0), the problem as "auto"
    resolves it where the first frames agree (:meth:`SysIdProblem.started_from_first_frames`),
    with a note of both costs; the chosen start's scan for :func:`_identify_from_scan`:
    (:func:`_scan` of the scan points and the guess with failures, seconds), None where no
    comparison ran). A first frame that is off starts every rollout from a wrong velocity,
    which no friction fits as well as the next frames' start; a right first frame followed by
    a motion that is no parabola (an engine's contact that hops, an impulse at the start)
    makes the next frames' parabola the wrong start. Both scans run in one program (the same
    layout, offsets 0); the chosen one is the identification's own (started from the first
    frames, the problem without offsets rolls out the same), so the comparison costs one."""
    plain = problem.started_from_first_frames()
    if plain is problem:
        return problem, None
    n = len(problem.parameters)
    at = np.vstack([scan_points(*scan_box(problem), scan), problem.initial()[None, :n]])  # (the guess last)
    t0, started = time.perf_counter(), time.time()
    scans = [_scan(p, at, failures=True) for p in (problem, dataclasses.replace(problem, start_velocity="first frames"))]
    seconds = _minus_compiling(t0, started) / 2
    after, first = (float(np.min(c[0][:-1])) for c in scans)
    if not first < after:
        return problem, (scans[0], seconds)
    note = (f"{FIRST_FRAMES_FIT_NOTE} {NEXT_FRAMES} "
            f"(a first frame may be off), but the rollouts started from each start's first three frames fit "
            f"better (the scan's lowest cost {first:.4g} against {after:.4g} from the next frames): a right first "
            "frame and a motion after it that is no parabola (a contact that hops, a push at the start); each "
            'rollout starts from its first frames (start_velocity = "first frames")')
    return dataclasses.replace(plain, notes=plain.notes + (note,)), (scans[1], seconds)


def _identify(problem: SysIdProblem, *, jacobian: str, max_iterations: int, xtol: float, ftol: float | None,
              gtol: float, horizons: tuple[float, ...], scan: int, starts: int, scanned=None) -> SysIdResult:
    """:func:`identify`'s scan (or continuation) and local solves; ``scanned``: the scan of
    :func:`_first_frames_if_they_fit`, where it ran one (the same points), not run again."""
    if scan:
        return _identify_from_scan(problem, scan, starts, jacobian=jacobian, max_iterations=max_iterations,
                                   xtol=xtol, ftol=ftol, gtol=gtol, horizons=horizons, scanned=scanned)
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
    return _local_solve(problem, problem.initial(), jacobian=jacobian, max_iterations=max_iterations, xtol=xtol,
                        ftol=ftol, gtol=gtol, check_start=True)


@dataclass(frozen=True)
class LeastSquaresFit:
    """The answer of :func:`solve_least_squares`.

    x (n,): the solution; cost: ½‖r(x)‖²; cost_history: the cost after each iteration (first:
    ``initial_cost`` when given); residuals (m,) and jacobian (m, n) at x (the Jacobian the
    solver last used: the given function's, or SciPy's finite differences); nfev/njev:
    residual/Jacobian evaluations; status: SciPy's (≤ 0: stopped at the evaluation limit or
    failed, before a convergence test was met); success/message: SciPy's; wall_time_s [s]."""

    x: np.ndarray
    cost: float
    cost_history: list
    residuals: np.ndarray
    jacobian: np.ndarray
    nfev: int
    njev: int
    status: int
    success: bool
    message: str
    wall_time_s: float

    @property
    def converged(self) -> bool:
        """Whether a convergence test (xtol, ftol or gtol) was met."""
        return self.status > 0


def solve_least_squares(residuals, x0: np.ndarray, lower: np.ndarray, upper: np.ndarray, *, jacobian=None,
                        max_iterations: int = 50, xtol: float = 1e-8, ftol: float = 1e-8, gtol: float = 1e-8,
                        initial_cost: float | None = None) -> LeastSquaresFit:
    """The local solver of identification: min ½‖r(x)‖² subject to lower ≤ x ≤ upper (n,),
    from ``x0`` (n,, inside the bounds), by :func:`scipy.optimize.least_squares`
    (trust-region reflective, columns scaled by the Jacobian). residuals: x (n,) -> (m,)
    NumPy float64; jacobian: x -> (m, n), or None for SciPy's 2-point finite differences;
    max_iterations: the most residual evaluations (SciPy's ``max_nfev``); initial_cost: the
    cost at x0 when the caller has it (the first entry of the cost history). Standard errors
    from the answer: :func:`least_squares_standard_errors`."""
    history = [] if initial_cost is None else [float(initial_cost)]

    def callback(intermediate_result):
        history.append(float(intermediate_result.cost))

    t0 = time.perf_counter()
    sol = least_squares(residuals, x0, jac=jacobian or "2-point", bounds=(lower, upper), method="trf",
                        x_scale="jac", max_nfev=max_iterations, xtol=xtol,
                        ftol=ftol, gtol=gtol, callback=callback)
    wall = time.perf_counter() - t0
    return LeastSquaresFit(x=np.asarray(sol.x), cost=float(sol.cost), cost_history=history,
                           residuals=np.asarray(sol.fun), jacobian=np.asarray(sol.jac), nfev=int(sol.nfev),
                           njev=int(sol.njev or 0), status=int(sol.status), success=bool(sol.success),
                           message=str(sol.message), wall_time_s=wall)


def least_squares_standard_errors(fit: LeastSquaresFit, free: np.ndarray | None = None) -> np.ndarray | None:
    """Standard errors (n,) of a least-squares answer from σ²(JᵀJ)⁻¹, σ² = 2·cost/(m − n_free),
    over the ``free`` parameters (a boolean mask (n,); default all; the others NaN: e.g. those
    at a bound, the fit conditional on them); all NaN when no convergence test was met; None
    when JᵀJ is singular."""
    m, n = fit.residuals.shape[0], fit.x.shape[0]
    free = np.ones(n, dtype=bool) if free is None else np.asarray(free, dtype=bool)
    se = np.full(n, np.nan)
    if not fit.converged:
        return se
    J = fit.jacobian[:, free]
    sigma2 = 2 * fit.cost / max(m - int(free.sum()), 1)
    try:
        cov = sigma2 * np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return None
    se[free] = np.sqrt(np.clip(np.diag(cov), 0, None))
    return se


#: the local solve ends when an iteration lowers the cost by less than this fraction of the
#: residual variance σ² (:func:`statistical_ftol`)
COST_TOLERANCE = 1e-3


def statistical_ftol(num_residuals: int, num_parameters: int) -> float:
    """SciPy's ``ftol`` (an iteration ends the solve when it lowers the cost F = ½‖r‖² by
    less than ftol·F, the step agreeing with its model) that means a decrease below
    :data:`COST_TOLERANCE`·σ², σ² = 2F/(m − n) the residual variance of m residuals and n
    parameters: ftol = 2·COST_TOLERANCE/(m − n). Moving a parameter by one standard error
    raises the cost by σ²/2, so the solve stops where further iterations move the estimate
    by a small fraction of its uncertainty, not of its value. Where the model misfits the
    data (the residuals large, e.g. another engine's motion), Gauss–Newton's curvature
    underestimates the cost's and it converges linearly, crawling along a valley for
    hundreds of evaluations at the fixed 1e-8: on a bunny's slide made by plain MuJoCo C
    (14 parameters), 1e-8 ran to the evaluation limit (140) without a convergence test
    met, this stopped after 23, 0.1 standard errors from where the 140 had crawled. The test
    stays relative to F, so a fit to noise-free data (F near 0, Gauss–Newton converging
    quadratically) still ends at rounding. The bootstrap's refits keep SciPy's 1e-8: they
    start at the estimate, and stopping them early would shrink their spread."""
    return 2.0 * COST_TOLERANCE / max(num_residuals - num_parameters, 1)


def _local_solve(problem: SysIdProblem, x0: np.ndarray, *, jacobian: str, max_iterations: int,
                 xtol: float, ftol: float | None, gtol: float, check_start: bool = False) -> SysIdResult:
    """Bounded least squares from ``x0`` (n,) with the problem's compiled residual and Jacobian
    (compiled on first use; that time is reported as compile_time_s); ftol None:
    :func:`statistical_ftol`. check_start: raise :class:`_SingleStepsFail` where the problem
    takes single steps and steps fail at ``x0`` (AD Jacobians: their program's flags, no
    evaluation of their own)."""
    lo, hi = problem.bounds()
    if ftol is None:
        ftol = statistical_ftol(problem.num_residuals, problem.num_parameters)

    f = unc.least_squares_functions(problem, jacobian=jacobian == "ad")
    t0 = time.perf_counter()
    r0 = f.raw(x0)  # remembered: the solver's first evaluation reuses it
    compile_time = time.perf_counter() - t0
    if not np.all(np.isfinite(r0)):
        raise _NonFiniteStart("the simulation gives non-finite residuals at the initial guess; check the scene and "
                              "data")
    if check_start and jacobian == "ad" and problem.failure_substeps == 1:
        failed = problem.failed_steps(x0)
        if failed.any():
            raise _SingleStepsFail(_failed_summary(_per_trajectory(problem, failed), "at the initial guess"))

    fit = solve_least_squares(f.fun, x0, lo, hi, jacobian=f.jac, max_iterations=max_iterations, xtol=xtol, ftol=ftol,
                              gtol=gtol, initial_cost=0.5 * float(r0 @ r0))
    if f.compress:  # the residual's own rows, for the standard errors and the checks after the solve
        r, J = f.full(fit.x)
        fit = dataclasses.replace(fit, residuals=r, jacobian=J)
    m = len(fit.residuals)
    se, notes = _standard_errors(problem, fit, max_iterations)
    return SysIdResult(
        labels=problem.labels, estimates=fit.x, standard_errors=se, initial=x0,
        cost_history=fit.cost_history, final_cost=fit.cost, rms_residual=float(np.sqrt(2 * fit.cost / m)),
        num_residuals=m, nfev=fit.nfev, njev=fit.njev, wall_time_s=fit.wall_time_s,
        compile_time_s=compile_time, success=fit.success, message=fit.message, jacobian=jacobian,
        warnings=notes, jacobian_matrix=fit.jacobian,
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


def _standard_errors(problem: SysIdProblem, fit: LeastSquaresFit,
                     max_iterations: int) -> tuple[np.ndarray, list[str]]:
    """Standard errors from σ²(JᵀJ)⁻¹ (n,) and the warnings that go with them: none when the
    solver did not meet a convergence test; none for a parameter at a bound, the others from
    the Jacobian without its column (the fit conditional on the bound)."""
    n = fit.x.shape[0]
    if not fit.converged:
        return np.full(n, np.nan), [f"the solver stopped at its evaluation limit ({max_iterations}) "
                                    f"{_EVALUATION_LIMIT} (not a converged minimum)"]
    notes, free = [], np.ones(n, dtype=bool)
    for i, side in at_bound(problem, fit.x):
        free[i] = False
        p = problem.parameters[i]
        notes.append(f"{p.label} = {fit.x[i]:.6g}{_AT_BOUND} {side} bound: no standard error (the cost may keep "
                     "falling beyond it; widen the bound if that is physical)")
    se = least_squares_standard_errors(fit, free)  # AD's Jacobian, or SciPy's finite differences, at the solution
    if se is None:
        notes.append(_SINGULAR)
        se = np.full(n, np.nan)
    return se, notes


# what a local solve says of its own answer (:func:`_standard_errors`, :func:`_at_point`): said
# again of each new answer, never carried over from an earlier one
_AT_BOUND = " sits at its"
_SINGULAR = "JᵀJ is singular: the data do not determine every parameter; no standard errors"
_EVALUATION_LIMIT = "before a convergence test was met: no standard errors"
_AT_POINT = ("the local solver did not improve on the lowest point the checks evaluated; that point is reported "
             "(its standard errors from the Jacobian there)")


def _of_another_answer(warning: str) -> bool:
    """Whether ``warning`` speaks of a particular answer's bounds, standard errors or point."""
    return (_AT_BOUND in warning or warning == _SINGULAR or _EVALUATION_LIMIT in warning
            or warning == _AT_POINT)


def _basin_starts(points: np.ndarray, costs: np.ndarray, lo: np.ndarray, hi: np.ndarray, scan: int,
                  starts: int) -> list[int]:
    """Indices of at most ``starts`` of the scanned points (K, n) to start local solves from,
    lowest cost first: only points with no lower-cost point within a critical distance (the
    rule of multi-level single linkage, Rinnooy Kan & Timmer 1987), so that two starts do not
    descend the same basin. The distance, in the box scaled to the unit cube: one grid step
    along each axis and its diagonals for a grid (n ≤ 2), the mean spacing K^(-1/n) of the
    Sobol points beyond. Non-finite costs are never starts. The soap's 15-point scan: the two
    lowest points (friction 0.714 and 0.857, one basin, both solves ending at 0.517) before;
    now 0.714 and 1.857, a shallow second basin on the high-friction plateau (its solve ends
    at 1.728, cost 0.33 against 0.024); an analytic slide: one start instead of two."""
    n = points.shape[1]
    u = (points - lo) / np.where(hi > lo, hi - lo, 1.0)
    step = 1.0 / max(scan - 1, 1) if n <= 2 else len(points) ** (-1.0 / n)
    radius = 1.01 * step * (np.sqrt(n) if n <= 2 else 1.0)
    finite = np.isfinite(costs)
    chosen: list[int] = []
    for i in (int(j) for j in np.argsort(costs) if finite[j]):
        lower = finite & (costs < costs[i])
        if np.any(lower & (np.linalg.norm(u - u[i], axis=1) <= radius)):
            continue  # downhill from a lower point: its basin has (or will have) a start
        chosen.append(i)
        if len(chosen) == starts:
            break
    return chosen


def _evaluate(problem: SysIdProblem, x: np.ndarray, jacobian: str) -> None:
    """One evaluation at the global parameters ``x`` (the others at their initial values), to
    compile (or load) the program the local solves share."""
    x0 = np.concatenate([x, problem.initial()[len(problem.parameters):]])
    problem.residuals_and_jacobian(x0) if jacobian == "ad" else problem.residuals_only(x0)


def _minus_compiling(t0: float, started: float) -> float:
    """Seconds since ``t0`` (``time.perf_counter()``) less those spent compiling since
    ``started`` (``time.time()`` at the same moment): the wall times that results report
    beside their ``compile_time_s``."""
    return max(0.0, time.perf_counter() - t0 - compile_seconds(started))


def _identify_from_scan(problem: SysIdProblem, scan: int, starts: int, scanned=None, **local) -> SysIdResult:
    n = len(problem.parameters)
    if n == 0:
        raise DanoError("a global scan needs global parameters (only per-segment nuisance offsets are fitted)")
    lo, hi = scan_box(problem)
    t0, started = time.perf_counter(), time.time()
    points = scan_points(lo, hi, scan)
    guess = problem.initial()[:n]
    # the local solves' program compiles (or loads) while the scan's runs
    warmed = in_background(lambda: _evaluate(problem, guess, local["jacobian"])) if not local["horizons"] else None
    if scanned is None:
        costs_all, diverged, failed = _scan(problem, np.vstack([points, guess[None]]), failures=True)  # (the guess too)
        scan_time = _minus_compiling(t0, started)
    else:  # (:func:`_first_frames_if_they_fit`'s, at the same points)
        (costs_all, diverged, failed), scan_time = scanned
    costs = costs_all[:-1]
    order = _basin_starts(np.vstack([points, guess[None]]), costs_all, lo, hi, scan, starts)
    if not order:
        raise DanoError("every point of the global scan gives a diverging simulation; check the bounds")
    where = f"at the {len(order)} scan points the local solves would start from"
    # (there the scan's costs are runaways'; a warm-up in a thread finishes on its own)
    if problem.failure_substeps == 1 and diverged[order].any():
        raise _SingleStepsFail(f"diverged in {int(diverged[order].any(axis=0).sum())} of {diverged.shape[1]} "
                               f"trajectories {where}")
    if problem.failure_substeps == 1 and failed[order[0]].any():  # (another start's answer is checked if it wins)
        raise _SingleStepsFail(_failed_summary(failed[order[0]],
                                               "at the scan's lowest point, where the first local solve starts"))
    inset = 0.02 * (hi - lo)  # a start on a bound may never leave it: moved inside
    candidates = [guess if i == len(points) else np.clip(points[i], lo + inset, hi - inset) for i in order]
    opts = {k: v for k, v in local.items() if k != "horizons"}
    t_local, started = time.perf_counter(), time.time()
    if local["horizons"]:  # continuation: truncated problems (compiled once per structure), one start at a time
        outcomes = [or_error(lambda x=x: _identify(problem.with_initial(x), scan=0, starts=starts, **local))
                    for x in candidates]
    else:  # one compiled residual and Jacobian for every start: the starts side by side
        outcomes = side_by_side([lambda x=x: _local_solve(problem, np.concatenate([x, problem.initial()[n:]]), **opts)
                                 for x in candidates],
                                warm=warmed)
    # a start whose rollout is non-finite (e.g. the given guess) is skipped
    results = [r for r in outcomes if not isinstance(r, DanoError)]
    kept = [x for x, r in zip(candidates, outcomes) if not isinstance(r, DanoError)]
    if not results:
        raise DanoError("no start of the global scan gives finite residuals")
    candidates = kept
    best = min(results, key=lambda r: r.final_cost)
    best.initial = problem.initial()
    # the starts' wall time (they may have run side by side), compiling left out
    best.wall_time_s = scan_time + _minus_compiling(t_local, started)
    best.nfev = sum(r.nfev for r in results) + len(points)
    best.njev = sum(r.njev for r in results)
    best.scan = {
        "points": points.tolist(),
        "cost": [None if not np.isfinite(c) else float(c) for c in costs],
        "guess_cost": None if not np.isfinite(costs_all[-1]) else float(costs_all[-1]),
        "budget": f"{len(points)} points ({'grid' if n <= 2 else 'scrambled Sobol'} over " + ", ".join(
            f"{p.label} [{a:.4g}, {b:.4g}]" for p, a, b in zip(problem.parameters, lo, hi)) + f"), {len(candidates)}"
            " local starts",
        "starts": [np.asarray(x).tolist() for x in candidates],
        "start_results": [{"estimates": r.estimates[:n].tolist(), "final_cost": r.final_cost} for r in results],
        "profile": _profiles([p.label for p in problem.parameters], points, costs, bins=max(scan, 8)),
        "wall_time_s": scan_time,
    }
    best.warnings = best.warnings + _disagreement(problem, best, results, float(np.min(costs))) \
        + _divergence_warning(problem, np.vstack([points, guess[None]]), diverged)
    return best


def _noise_and_misfit(problem: SysIdProblem, result: SysIdResult) -> dict:
    """The measurement noise estimated from the observations (:func:`~dano.sysid.uncertainty.
    observation_noise`), the rms residual it alone would leave, and a warning on the result
    when the fit's rms residual is well above it (a model that misfits the data)."""
    noise = unc.observation_noise(problem)
    expected = unc.expected_rms(problem, noise)
    noise["expected_rms_residual"] = expected
    noise["misfit_ratio"] = None if not expected else result.rms_residual / expected
    if expected is not None and result.rms_residual > MISFIT_RATIO * expected and result.rms_residual > 1e-7:
        shares = residual_shares(problem, result.estimates)
        noise["residual_shares"] = shares
        result.warnings.append(_misfit_warning(result.rms_residual, expected, noise["position_m"], shares,
                                               _spin_remedies(problem)))
    start = start_velocity_warning(problem, noise)
    if start:
        result.warnings.append(start)
    return noise


def residual_shares(problem: SysIdProblem, theta) -> dict:
    """{kind: share of the squared residual ‖r‖² at ``theta`` (n,) (the problem's parameter
    vector, :attr:`SysIdProblem.parameters` order, their units)} over
    :meth:`SysIdProblem.residual_kinds` ("position", "rotation", "joint", "start prior"), the
    kinds the residual has (shares sum to 1; all 0 where the residual is 0; non-finite
    residuals count as 0): where a misfit lies."""
    r = unc.finite(problem.residuals(theta), 0.0)
    kinds = problem.residual_kinds()
    total = float(r @ r)
    return {k: (float(r[kinds == k] @ r[kinds == k]) / total if total > 0 else 0.0) for k in dict.fromkeys(kinds)}


def _spin_remedies(problem: SysIdProblem) -> list[str]:
    """What the problem could still do about a misfit in the rotations of an object that spins
    while it slides (docs/own-object.md, step 4): identify ``torsional_friction`` (where not
    fitted) and take the per-sample model (where a pair has another)."""
    out = []
    if not any(p.name == "torsional_friction" for p in problem.parameters):
        out.append("identify torsional_friction too")
    if any(p.model.name != "per_sample" for p in problem.scene.info.pairs):
        out.append('take contact_model = "per_sample"')
    return out


def _misfit_warning(rms: float, expected: float, position_noise, shares: dict | None = None,
                    remedies: Sequence[str] = ()) -> str:
    """The warning of a fit whose rms residual ``rms`` is above MISFIT_RATIO times the
    ``expected`` one (residual units) that the observations' own noise (``position_noise``
    (3,) [m]) would leave: for noise-free observations (noise below
    :data:`~dano.sysid.problem.NOISE_FLOOR` on every axis) a model that does not reproduce
    the motion, not a ratio to rounding. ``shares``: :func:`residual_shares` at the fit, said
    where the residual has more than one kind (where the misfit lies); where most of it lies in
    the rotations, the ``remedies`` for a spin (:func:`_spin_remedies`) follow."""
    where = ""
    if shares and len(shares) > 1:
        ranked = sorted(shares.items(), key=lambda kv: -kv[1])
        parts = [f"{v:.0%} in the {k}s" if k != "start prior" else f"{v:.0%} in the start prior"
                 for i, (k, v) in enumerate(ranked) if i == 0 or v >= 0.005]
        where = f"; of the residual's square, {', '.join(parts)}" + (
            " (fit.png shows positions and rotations)" if "rotation" in shares else "")
        if shares.get("rotation", 0.0) > 0.5 and remedies:
            where += (f"; where an object spins while it slides, {' or '.join(remedies)} "
                      "(docs/own-object.md, step 4)")
    if np.max(position_noise) < NOISE_FLOOR:
        return (f"the model misfits the data: the observations are free of noise (their third differences are at "
                f"rounding, {np.max(position_noise):.1g} m) and the fit leaves an rms residual of {rms:.3g}: the "
                "model does not reproduce the motion exactly (e.g. another engine's); the standard errors, which "
                f"assume noise, mean little here{where}")
    return (f"the model misfits the data: rms residual {rms:.3g} is {rms / expected:.3g}x what the observations' own "
            f"noise would leave ({expected:.3g}, from differences of neighbouring frames), or their errors are "
            "correlated from frame to frame (a video tracker's are), which that estimate does not see; the standard "
            "errors understate the uncertainty, and the interval allows for correlated residuals, not for the "
            f"model's own error (check the scene, the object's size and mass and the fixed contact parameters){where}")


def start_velocity_warning(problem: SysIdProblem, noise: dict) -> str | None:
    """A warning when the rollouts start from velocities that finite differences of noisy
    frames make uncertain along the weighed axes not fitted: by g·σ/Δt (σ the position
    noise estimated from the observations, Δt the frame interval, g the stencil's
    :func:`~dano.sysid.problem.finite_difference_gain`), more than
    :data:`~dano.sysid.problem.START_VELOCITY_NOISE` of the moving starts' median speed
    (:func:`~dano.sysid.problem.noisy_start_velocities`, which leaves out starts with
    measured velocities, a given ``qvel0`` or ``rest_frames``), or, where the rollouts start
    from their first frames (``start_velocity="first frames"``), first frames that disagree so
    with the motion after them (:func:`~dano.sysid.problem.stray_start_velocities`), unless
    :func:`identify` started them there because they fit better (:func:`_first_frames_if_they_fit`,
    said in the notes). None where there is nothing to say."""
    weighed = [a for a, w in zip("xyz", problem.weights.position) if w > 0]
    missing = "".join(a for a in weighed if a not in problem.fit_velocity)
    why = noisy_start_velocities(problem.observations, problem.segments, noise.get("position_m"), missing,
                                 problem.substeps)
    chosen = any(n.startswith(FIRST_FRAMES_FIT_NOTE) for n in problem.notes)
    if why is None and problem.start_velocity == "first frames" and not chosen:
        why = stray_start_velocities(problem.observations, problem.segments, noise.get("position_m"), missing)
    if why is None:
        return None
    suggest = "".join(a for a in "xyz" if a in missing or a in problem.fit_velocity)
    return (f"{why}, which can move the estimate far: fit them as nuisance parameters (fit_velocity = "
            f"\"{suggest}\" or \"auto\"; TOML [options]), or give measured velocities")


#: a fit whose rms residual exceeds this multiple of what the estimated noise leaves misfits
MISFIT_RATIO = 2.0
BOOTSTRAP_RESAMPLES = 200


def _continued(best: SysIdResult, new: SysIdResult) -> SysIdResult:
    """``new``, a local solve continued from a point that ``best``'s checks found, with what
    ``best`` carries over: the scan, the stages, the user's initial guess, the segment scan,
    its evaluations and times added, and its warnings but the scan's early-stop one."""
    new.scan, new.stages, new.segment_scan = best.scan, best.stages, best.segment_scan
    new.initial = best.initial  # the user's guess, not the restart's point
    new.wall_time_s += best.wall_time_s
    new.compile_time_s += best.compile_time_s
    new.nfev += best.nfev
    new.njev += best.njev
    new.warnings = [w for w in best.warnings
                    if "scan saw a lower cost" not in w and not _of_another_answer(w) and w not in new.warnings] \
        + new.warnings
    return new


#: a segment whose cost exceeds this multiple of the median segment's is re-scanned
#: (:func:`segment_restarts`)
SEGMENT_OUTLIER = 10.0
#: candidates per re-scanned segment (its initial block, its block in earlier rounds' fits, then
#: scrambled Sobol points)
SEGMENT_CANDIDATES = 32
#: rounds of re-scan and local solve at most
SEGMENT_ROUNDS = 2


def segment_restarts(problem: SysIdProblem, best: SysIdResult, *, level: float = 0.95, jacobian: str = "ad",
                     max_iterations: int | None = None, xtol: float = 1e-8, ftol: float | None = None,
                     gtol: float = 1e-8) -> SysIdResult:
    """Restarts of the segments that a local solve left fitted far worse than the others.

    With the global parameters held, the cost is separable: each segment's nuisance block
    (its start offsets) moves its own rows only (:meth:`SysIdProblem.segment_entries`). A
    solve of many segments can leave one block in a local minimum of its own (an impact's
    jagged cost: on 40 noisy slides of a bunny made by plain MuJoCo C, two data sets, one
    slide at 160–200× the median slide's cost held the whole fit at 3.2–4.4× the cost it
    reaches once that slide is moved), which the verification's profiles (the nuisance
    re-optimised by chord steps) need not leave (docs/sysid.md). A segment costing more than
    :data:`SEGMENT_OUTLIER` times the median segment's, by more than χ²(level)·σ² (σ² the
    residual variance), is re-scanned: :data:`SEGMENT_CANDIDATES` values of its block, its
    initial value, its value in each earlier round's fit (where the continued solve pushed
    another segment into a minimum of its own) and scrambled Sobol points within ± twice the
    spread (standard deviation over the segments) of each of its entries around the fitted
    value, every such segment's candidates evaluated at once (K vectors of θ through the
    vmapped residual). Each takes its lowest candidate where that lowers its own cost by more
    than χ²(level)·σ²; the local solver continues from there and its answer is kept when it
    costs less, for at most :data:`SEGMENT_ROUNDS` rounds. jacobian, max_iterations, xtol,
    ftol, gtol: the local solver's, as :func:`identify` takes them (max_iterations None:
    max(50, 10 × the parameters)).

    best: a local solve's result on ``problem`` (its ``estimates`` (n,) and ``final_cost``).
    Raises DanoError if ``level`` is not in (0, 1).

    Returns ``best`` or the continued result; its ``segment_scan`` records each round
    (segments re-scanned, their costs and the median's, those moved, the cost before and
    after, wall time) and a note says what changed; ``segment_scan`` stays None where no
    segment is an outlier, and with fewer than three segments or no nuisance blocks.
    """
    if not 0 < level < 1:
        raise DanoError(f"level must lie in (0, 1), got {level}")
    local = dict(jacobian=jacobian, max_iterations=max_iterations or max(50, 10 * problem.num_parameters),
                 xtol=xtol, ftol=ftol, gtol=gtol)
    entries = problem.segment_entries()
    if len(entries) < 3 or not any(len(b) for _, b in entries):
        return best
    kinds = np.array([re.sub(r"\[\d+\]", "", lab) for lab in problem.labels], dtype=object)  # v0[3]:toy:x -> v0:toy:x
    rounds, started, t0 = [], time.time(), time.perf_counter()
    earlier = [problem.initial()]  # blocks to try again: the initial ones, then each round's fit before it
    for _ in range(SEGMENT_ROUNDS):
        theta = best.estimates
        r = problem.residuals(theta)
        cost = np.array([0.5 * float(r[rows] @ r[rows]) for rows, _ in entries])
        sigma2 = 2 * best.final_cost / max(len(r) - problem.num_parameters, 1)
        significant = unc.chi2_threshold(level) * sigma2
        median = float(np.median(cost))
        outliers = [s for s, c in enumerate(cost)
                    if len(entries[s][1]) and c > SEGMENT_OUTLIER * median and c - median > significant]
        if not outliers:
            break
        fitted = np.concatenate([b for _, b in entries])
        spread = {k: max(float(np.std(theta[fitted][kinds[fitted] == k])), 1e-3) for k in set(kinds[fitted])}
        from scipy.stats import qmc  # (imported where needed: see scan_points)
        width = max(len(entries[s][1]) for s in outliers)
        unit = qmc.Sobol(d=width, scramble=True, seed=0).random_base2(int(np.log2(SEGMENT_CANDIDATES)))
        thetas = np.repeat(theta[None], SEGMENT_CANDIDATES, axis=0)
        h, tried = len(earlier), np.stack(earlier)
        for s in outliers:
            b = entries[s][1]
            scale = 2 * np.array([spread[k] for k in kinds[b]])
            thetas[:h, b] = tried[:, b]
            thetas[h:, b] = theta[b] + (2 * unit[h:, : len(b)] - 1) * scale
        with np.errstate(over="ignore", invalid="ignore"):  # (a diverging candidate: inf)
            R = problem.batch_residuals(thetas)
            C = np.stack([0.5 * np.sum(R[:, entries[s][0]] ** 2, axis=1) for s in outliers], axis=1)
        C = np.where(np.isfinite(C), C, np.inf)
        x0, moved = theta.copy(), []
        for j, s in enumerate(outliers):
            k = int(np.argmin(C[:, j]))
            if C[k, j] < cost[s] - significant:
                x0[entries[s][1]] = thetas[k, entries[s][1]]
                moved.append(s)
        record = {"segments": [int(s) for s in outliers], "costs": [float(cost[s]) for s in outliers],
                  "median_cost": median, "moved": [int(s) for s in moved], "cost_before": best.final_cost}
        rounds.append(record)
        if not moved:
            break
        new = _local_solve(problem, x0, **local)
        record["cost_after"] = new.final_cost
        earlier.append(theta)
        if not new.final_cost < best.final_cost:
            break
        best = _continued(best, new)
    if not rounds:
        return best
    best.segment_scan = {"rounds": rounds, "candidates": SEGMENT_CANDIDATES,
                         "wall_time_s": _minus_compiling(t0, started)}
    best.wall_time_s += best.segment_scan["wall_time_s"]
    first = rounds[0]
    if best.final_cost < first["cost_before"]:
        outcome = (f"the fit continued from their lowest candidates, cost {first['cost_before']:.6g} -> "
                   f"{best.final_cost:.6g}")
    elif first["moved"]:
        outcome = f"the fit continued from their lowest candidates reached {first['cost_after']:.6g}, no lower; kept"
    else:
        outcome = "no candidate lowered a segment's cost; the fit is kept"
    best.notes.append(f"{len(first['segments'])} segment(s) fitted at over {SEGMENT_OUTLIER:g}x the median segment's "
                      f"cost ({_segment_names(problem, first['segments'])}) were re-scanned: {outcome}")
    return best


def _segment_names(problem: SysIdProblem, segments: list[int], shown: int = 5) -> str:
    """Segments named by trajectory and first frame: "trajectory 17 from frame 0", at most ``shown``."""
    names = [f"trajectory {problem.segments[s].obs} from frame {problem.segments[s].start}" for s in segments]
    return ", ".join(names[:shown]) + (f" and {len(names) - shown} more" if len(names) > shown else "")


def _verify_and_assess(problem: SysIdProblem, best: SysIdResult, points: int, level: float, seed: int,
                       local: dict) -> SysIdResult:
    """Profiles through the estimate (verification: continue from any lower point the tool
    evaluated), then the interval, the standard errors' check, identifiability and misfit."""
    n = len(problem.parameters)
    lo, hi = problem.bounds()
    box_lo, box_hi = scan_box(problem)
    box = box_hi - box_lo
    spacing = box / (default_scan(n) - 1) if best.scan is None else box / (max(len(best.scan["points"]) ** (1 / n),
                                                                                 2) - 1)
    scan_pts = None
    if best.scan is not None:
        c = np.array([np.inf if v is None else v for v in best.scan["cost"]])
        scan_pts = (np.asarray(best.scan["points"]), c)
    t0, started = time.perf_counter(), time.time()
    restarts, widths, refined, profiles, evaluated = 0, {}, set(), {}, 0
    level_q = unc.chi2_threshold(level)
    use_boot = len(problem.observations) >= unc.BOOTSTRAP_MIN_TRAJECTORIES
    record = (np.inf, None)  # the lowest cost the tool evaluated, and where
    if scan_pts is not None and np.isfinite(np.min(scan_pts[1])):
        k = int(np.argmin(scan_pts[1]))
        record = (float(scan_pts[1][k]), np.concatenate([scan_pts[0][k], problem.initial()[n:]]))
    for attempt in range(12):  # profiles, restarts from lower points, widening and refining
        theta = best.estimates
        J = best.jacobian_matrix if best.jacobian_matrix is not None else problem.jacobian(theta)
        for i in range(n):
            if i not in widths:
                se = best.standard_errors[i]
                widths[i] = min(max(5 * se if np.isfinite(se) else 0.0, spacing[i], 1e-3 * box[i]), box[i])
            if i not in profiles:
                a, b = max(lo[i], theta[i] - widths[i]), min(hi[i], theta[i] + widths[i])
                profiles[i] = pr = unc.profile(problem, theta, J, i, a, b, points)
                evaluated += points
                k = int(np.argmin(pr.costs))
                if pr.costs[k] < record[0]:
                    record = (float(pr.costs[k]), pr.thetas[k])
        # verification: continue from the lowest point evaluated when it costs less than the estimate
        if record[0] < best.final_cost - 1e-9 * max(best.final_cost, 1e-300):
            r = problem.residuals(record[1])  # the batched evaluation's cost, confirmed unbatched
            confirmed = 0.5 * float(r @ r)
            if not confirmed < best.final_cost:  # a rounding difference on a chaotic cost, not a lower point
                record = (best.final_cost, best.estimates)
            else:
                record = (confirmed, record[1])
        if record[0] < best.final_cost - 1e-9 * max(best.final_cost, 1e-300) and attempt < 10:
            if restarts < 4:
                restarts += 1
                new = _local_solve(problem, np.clip(record[1], lo, hi), **local)
            else:
                new = best
            if new.final_cost >= record[0]:  # the solver did not improve on the point: it is the answer
                new = _at_point(problem, new, record[1])
            if new is not best:
                new = _continued(best, new)
            best, profiles = new, {}
            continue
        # intervals; widen where they reach the profile's end (not a bound), refine where coarse
        r = problem.residuals(best.estimates)
        sigma2 = 2 * best.final_cost / max(len(r) - problem.num_parameters, 1)
        rho = unc.residual_autocorrelation(problem, r)
        kappa = (1 + rho) / (1 - rho)
        threshold = level_q * sigma2 * kappa
        redo, out = {}, {}
        rng = np.random.default_rng(seed)
        for i, pr in profiles.items():
            lower, upper, at_a, at_b = unc.profile_interval(pr.values, pr.costs, threshold, best.estimates[i])
            step = pr.values[1] - pr.values[0]
            boot = unc.profile_bootstrap(pr, BOOTSTRAP_RESAMPLES, rng) if use_boot else None
            open_a, open_b = pr.values[0] > lo[i] + 1e-12, pr.values[-1] < hi[i] - 1e-12
            boot_end = boot is not None and boot[1] > 0.025 * BOOTSTRAP_RESAMPLES
            if ((at_a and open_a) or (at_b and open_b) or (boot_end and (open_a or open_b))) \
                    and widths[i] < box[i] * 4:
                redo[i] = widths[i] * 4
            elif (upper - lower) < 6 * step and i not in refined and upper > lower:
                redo[i] = max(1.5 * (upper - lower), 1e-9 * max(box[i], 1.0))
                refined.add(i)
            out[i] = (lower, upper, boot)
        if not redo or attempt >= 10:
            break
        for i, w in redo.items():
            widths[i] = w
            profiles.pop(i)
    if problem.failure_substeps == 1:
        _check_profiles(problem, profiles, out, threshold)
    if record[0] < best.final_cost - 1e-9 * max(best.final_cost, 1e-300):  # checks exhausted: the point itself
        best = _at_point(problem, best, record[1])
    best.verification = {"restarts": restarts, "profile_points_evaluated": evaluated,
                         "lowest_evaluated_cost": record[0],
                         "wall_time_s": _minus_compiling(t0, started)}
    best.wall_time_s += best.verification["wall_time_s"]
    _assess(problem, best, profiles, out, sigma2, rho, kappa, threshold, level, level_q)
    best.noise = _noise_and_misfit(problem, best)
    return best


def _check_profiles(problem: SysIdProblem, profiles: dict, intervals: dict, threshold: float) -> None:
    """Raise :class:`_SingleStepsFail` where single steps fail at points of the verification's
    ``profiles`` inside their ``intervals`` ({index: (lower, upper, ...)}) and that matters:
    taken again in substeps, a point's cost moves by more than the interval's cost
    ``threshold``. (Those points' rollouts again, in a program of its own: only where a step
    failed.)"""
    inside = [(pr, (pr.values >= intervals[i][0]) & (pr.values <= intervals[i][1])) for i, pr in profiles.items()]
    thetas = np.concatenate([pr.thetas[k & (pr.failed > 0)] for pr, k in inside])
    if not len(thetas):
        return
    costs = np.concatenate([pr.costs[k & (pr.failed > 0)] for pr, k in inside])
    R = problem.with_failure_substeps(DEFAULT_FAILURE_SUBSTEPS).batch_residuals(thetas)
    with np.errstate(over="ignore", invalid="ignore"):
        moved = np.abs(0.5 * np.sum(R**2, axis=1) - costs)
    if not np.all(moved <= threshold):  # (a non-finite cost counts as moved)
        biggest = float(np.max(np.where(np.isfinite(moved), moved, np.inf)))
        raise _SingleStepsFail(
            f"had failed steps at {len(thetas)} of the {sum(int(k.sum()) for _, k in inside)} points of the "
            f"verification's profiles inside the interval (taken in substeps, the cost there moved by up to "
            f"{biggest:.3g}, above the interval's threshold {threshold:.3g})")


def _at_point(problem: SysIdProblem, result: SysIdResult, theta: np.ndarray) -> SysIdResult:
    """The result moved to an evaluated point ``theta`` (n,) whose cost is lower than the
    solver's answer: its cost, Jacobian and standard errors there, and the warnings of the
    answer it replaces about bounds and standard errors replaced by the point's own."""
    r = problem.residuals(theta)
    result.estimates = np.asarray(theta, dtype=np.float64)
    result.final_cost = float(0.5 * r @ r)
    result.rms_residual = float(np.sqrt(2 * result.final_cost / len(r)))
    result.jacobian_matrix = J = problem.jacobian(theta)
    fit = LeastSquaresFit(x=result.estimates, cost=result.final_cost, cost_history=[], residuals=r, jacobian=J,
                          nfev=0, njev=0, status=1, success=True, message="", wall_time_s=0.0)
    result.standard_errors, notes = _standard_errors(problem, fit, 0)
    result.warnings = [w for w in result.warnings if not _of_another_answer(w)] + notes + [_AT_POINT]
    return result


def _assess(problem, best, profiles, out, sigma2, rho, kappa, threshold, level, level_q) -> None:
    """Interval, standard errors' check and identifiability of each global parameter, in place."""
    n = len(problem.parameters)
    lo, hi = problem.bounds()
    box_lo, box_hi = scan_box(problem)
    z = np.sqrt(2 * level_q)
    n_obs = len(problem.observations)
    interval = {"level": level, "lower": {}, "upper": {}, "profile_likelihood": {}, "bootstrap": None,
                "noise_variance": sigma2, "autocorrelation": rho, "inflation": kappa,
                "method": "profile likelihood (noise variance from the residuals, x (1+rho)/(1-rho) for residuals "
                          "correlated in time; other parameters re-optimised by chord Gauss-Newton)"
                          + (f" and bootstrap over the {n_obs} trajectories ({BOOTSTRAP_RESAMPLES} resamples of the "
                             "per-trajectory profile costs); the hull of both"
                             if n_obs >= unc.BOOTSTRAP_MIN_TRAJECTORIES
                             else "; no bootstrap (fewer than "
                                  f"{unc.BOOTSTRAP_MIN_TRAJECTORIES} trajectories)")}
    bounds_hit = dict(at_bound(problem, best.estimates))
    for i in range(n):
        label = problem.parameters[i].label
        pr = profiles[i]
        lower, upper, boot = out[i]
        theta_i = best.estimates[i]
        interval["profile_likelihood"][label] = [lower, upper]
        if boot is not None:
            est = boot[0]
            std = float(np.std(est, ddof=1) * np.sqrt(n_obs / (n_obs - 1)))
            half = unc.t_quantile(level, n_obs - 1) * std
            b_lo, b_hi = max(theta_i - half, lo[i]), min(theta_i + half, hi[i])
            interval["bootstrap"] = interval["bootstrap"] or {}
            interval["bootstrap"][label] = {"lower": b_lo, "upper": b_hi, "std": std,
                                            "resamples_at_profile_end": int(boot[1])}
            lower, upper = min(lower, b_lo), max(upper, b_hi)
        interval["lower"][label], interval["upper"][label] = float(lower), float(upper)
        # the local curvature's standard error, where the profile at the interval's scale agrees
        lo0, hi0, _, _ = unc.profile_interval(pr.values, pr.costs, level_q * sigma2, theta_i)
        step = pr.values[1] - pr.values[0]
        se = best.standard_errors[i]
        ratio = (hi0 - lo0) / (2 * z * se) if np.isfinite(se) and se > 0 else None
        minima = unc.count_local_minima(pr.costs, 1e-3 * threshold)
        rough = (ratio is not None and (hi0 - lo0) >= 4 * step and not 0.5 <= ratio <= 2.0) or minima >= 2
        span_frac = (upper - lower) / max(box_hi[i] - box_lo[i], 1e-300)
        flat = span_frac >= 0.9 or (upper - lower) >= 0.9 * (pr.values[-1] - pr.values[0]) and \
            pr.values[0] <= lo[i] + 1e-12 and pr.values[-1] >= hi[i] - 1e-12
        predicted = 2 * z * se * np.sqrt(kappa)  # the interval's width the local curvature gives
        one_sided = _one_sided(pr, lower, upper, predicted, span_frac)
        if flat and not _falls_toward_bound(pr, bounds_hit.get(i), 1e-3 * threshold):
            status = "flat"  # before "at bound": on a flat cost the bound an estimate stops at means nothing
        elif i in bounds_hit:
            status = "at bound"
        elif one_sided is not None:
            status = "one-sided"
        elif rough:
            status = "rough"
        else:
            status = "identified"
        best.identifiability[label] = {"status": status, "local_minima_in_profile": minima,
                                       "curvature_ratio": ratio}
        if status == "flat":
            best.warnings = [w for w in best.warnings  # its "sits at its bound": widening would not help
                             if not (w.startswith(f"{label} = ") and " sits at its " in w)]
            _drop_from_minima(problem, best, label)
            best.warnings.append(
                f"{label} is not identifiable from these data: its cost stays within the noise over "
                f"[{lower:.4g}, {upper:.4g}]; more trajectories, or motions that depend on it more, would help"
                + ("; a DANO that touches only fixed geometry moves the same at any mass scale (its contact "
                   "forces and its mass both scale with alpha): alpha needs a body of known mass or a known force "
                   "acting on the object (a robot pushing it, another object)"
                   if problem.parameters[i].name == "alpha" else ""))
        elif status == "one-sided":
            best.standard_errors[i] = np.nan
            below = one_sided == ">="  # bounded from below only: the interval runs to the range's top
            best.warnings.append(
                f"{label} is bounded on one side only: its cost stays within the interval's threshold from "
                + (f"{lower:.4g} up to the top" if below else f"the bottom up to {upper:.4g}")
                + f" of the range evaluated ({pr.values[-1] if below else pr.values[0]:.4g}), so the data say only "
                + f"{label} {one_sided} {lower if below else upper:.4g}"
                + f"; the estimate {theta_i:.4g} is where the cost is lowest"
                + (f", and its local curvature's standard error ({se:.3g}, an interval of {predicted:.3g} with the "
                   "correlated residuals' inflation) describes only that minimum" if np.isfinite(se) and se > 0 else "")
                + ": no standard error is reported; motions that depend on it more would help"
                + ("; for a friction, slides on a face, which decelerate at friction x g (a toss that rolls or "
                   "tumbles depends on it little)" if "friction" in problem.parameters[i].name else ""))
        elif status == "rough":
            if np.isfinite(se):
                best.standard_errors[i] = np.nan
            best.warnings.append(
                f"{label}: the cost is rough at the scale of its interval ("
                + (f"{minima} local minima in the profile" if minima != 1 else "one local minimum in the profile")
                + f" over [{pr.values[0]:.4g}, {pr.values[-1]:.4g}]"
                + (f"; at the noise's own scale (before the correlated residuals' inflation), the local curvature's "
                   f"standard error {se:.3g} would give an interval {1 / ratio:.3g}x the profile's" if ratio else "")
                + "): no standard error is reported, the interval comes from the profile"
                + (" and the bootstrap" if boot is not None else "")
                + "; " + _rough_cost_hint(problem))
    best.interval = interval
    best.profiles = {problem.parameters[i].label: {"values": pr.values.tolist(),
                                                   "cost": [float(c) if np.isfinite(c) else None for c in pr.costs]}
                     for i, pr in sorted(profiles.items())}


def _rough_cost_hint(problem: SysIdProblem) -> str:
    """What smooths a rough cost, for the route the problem already takes: windows shorten the
    rollouts but restart each from a fitted state, so on a slide they keep only the deceleration
    within a window (½μg·(10 Δt)² = 2 cm at μ = 0.4, 100 Hz), the size of a tracked pose's error
    (docs/tracking.md: a tracked mallet's friction 0.05 with windows of 10, 0.41 without)."""
    if problem.window is None:
        return ("more trajectories smooth the cost; so do windows ([options] window or auto_windows) for "
                "motions that tumble or bounce, but on a slide or a push with tracking errors of a centimetre "
                "they can lose the friction, since each window restarts the velocity (docs/tracking.md)")
    if problem.window == "auto":
        return ("more trajectories smooth the cost of a problem already split into windows at its impacts "
                "(auto_windows)")
    return ("more trajectories, or longer windows (fewer restarts of the velocity), smooth the cost of a "
            f"problem already split into windows ({problem.window!r})")


def _one_sided(profile, lower: float, upper: float, predicted: float, span_frac: float) -> str | None:
    """">=" where an interval [lower, upper] bounds its parameter from below only, "<=" from
    above only, else None: the interval reaches one end of its ``profile``'s range (a bound,
    or as far as the profile was widened) and not the other, and it is more than twice as
    wide as ``predicted``, the width the local curvature's standard error gives at the
    interval's level (2·z·se·√κ; where that is not finite, wider than half the scanned box,
    ``span_frac`` >= 0.5). A review's mug tossed in plain MuJoCo C rolls and tumbles once it
    lands: its friction's cost stays within the threshold from 0.25 to the range's top, 2,
    where the standard error said 0.0012 (2026-12-02)."""
    values = np.asarray(profile.values, dtype=np.float64)
    tol = 1e-9 * max(abs(values[0]), abs(values[-1]), 1.0)
    at_bottom, at_top = lower <= values[0] + tol, upper >= values[-1] - tol
    if at_bottom == at_top:
        return None
    wide = upper - lower > 2 * predicted if np.isfinite(predicted) and predicted > 0 else span_frac >= 0.5
    return (">=" if at_top else "<=") if wide else None


def _falls_toward_bound(profile, side: str | None, tolerance: float) -> bool:
    """Whether a profile's cost is lower at the end on ``side`` ("lower" | "upper", the bound
    the estimate sits at) than at its other end by more than ``tolerance``: the data pull the
    parameter beyond the bound (widen it), however small the box."""
    if side is None:
        return False
    costs = np.asarray(profile.costs, dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(costs))
    if len(ok) < 2:
        return False
    near, far = (costs[ok[0]], costs[ok[-1]]) if side == "lower" else (costs[ok[-1]], costs[ok[0]])
    return bool(near < far - tolerance)


def _disagreement(problem: SysIdProblem, best: SysIdResult, results: list, scan_best: float) -> list[str]:
    """Warnings when the global search and the local fits disagree: another start ended within
    5 % of the best cost at estimates further than 3 standard errors (1e-3 of the bounds'
    span where there is none) from the best, i.e. local minima the standard errors do not
    cover; or the scan saw a lower cost than any local fit reached. The starts that disagree
    are kept in ``best.scan["local_minima"]`` (their estimates and the parameters that differ),
    so that a parameter found flat later is taken out of the note (:func:`_drop_from_minima`)."""
    n = len(problem.parameters)
    labels = [p.label for p in problem.parameters]
    span = np.array([p.upper - p.lower for p in problem.parameters])
    tol = np.where(np.isfinite(best.standard_errors[:n]), 3 * best.standard_errors[:n], 1e-3 * span)
    minima = []
    for r in results:
        if r is not best and r.final_cost <= 1.05 * best.final_cost + 1e-12:
            differs = np.abs(r.estimates[:n] - best.estimates[:n]) > tol
            if differs.any():
                minima.append({"estimates": r.estimates[:n].tolist(),
                               "differs": [lab for lab, d in zip(labels, differs) if d]})
    notes = []
    if best.scan is not None:
        best.scan["local_minima"] = minima
    if minima:
        notes.append(_minima_note(labels, best, minima))
    if scan_best < best.final_cost * (1 - 1e-9):
        notes.append(f"the scan saw a lower cost ({scan_best:.6g}) than every local fit reached "
                     f"({best.final_cost:.6g}): the local solver stopped early")
    return notes


#: the wording of the local-minima warning (:func:`_minima_note`) after its count
MINIMA_WARNING = "other start(s) ended within 5 % of the best cost at different estimates"


def _minima_note(labels: list[str], best: SysIdResult, minima: list[dict]) -> str:
    """The local-minima warning: how many starts ended near the best cost elsewhere, and the
    range of each parameter that differs between them and the best."""
    shown = [lab for lab in labels if any(lab in m["differs"] for m in minima)]
    values = np.array([m["estimates"] for m in minima] + [best.estimates[:len(labels)]])
    spread = ", ".join(f"{lab} {values[:, labels.index(lab)].min():.4g}..{values[:, labels.index(lab)].max():.4g}"
                       for lab in shown)
    return (f"{len(minima)} {MINIMA_WARNING} "
            f"({spread}): local minima; the standard errors understate the uncertainty (see the "
            "bootstrap or the scan's profile)")


def _drop_from_minima(problem: SysIdProblem, best: SysIdResult, label: str) -> None:
    """Takes a parameter found flat (not identifiable: its own warning says so) out of the
    local-minima warning; the warning goes where only flat parameters differed."""
    minima = (best.scan or {}).get("local_minima")
    if not minima or not any(label in m["differs"] for m in minima):
        return
    labels = [p.label for p in problem.parameters]
    kept = [{**m, "differs": [x for x in m["differs"] if x != label]} for m in minima]
    kept = [m for m in kept if m["differs"]]
    best.scan["local_minima"] = kept
    # (found by its wording: the best may have moved since it was written, by the verification's restarts)
    old = [w for w in best.warnings if MINIMA_WARNING in w]
    best.warnings = [w for w in best.warnings if w not in old] + ([_minima_note(labels, best, kept)] if kept else [])
