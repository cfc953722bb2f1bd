"""Honest uncertainty (issue 8, item 5): standard errors only at a converged interior minimum,
warnings that say why, and a bootstrap over trajectories that covers the truth."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest

from dano.asset import build
from dano.errors import DanoError
from dano.fields import BoxField
from dano.sim import DanoObject, compose
from dano.sysid import (FitParameter, Observation, SysIdProblem, SysIdResult, Weights, bootstrap, cramer_rao,
                        identify)
from dano.experiments.sysid_examples import analytic_slides, bootstrap_coverage
from dano.sysid.solve import _disagreement


@pytest.fixture(scope="module")
def box():
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    return compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.0025)


def slide_problem(scene, upper=2.0, trajectories=8, observations=None):
    # 8 trajectories of 20 frames: the structure of bootstrap_coverage's problems (the same box,
    # weights and base parameters), so that the file compiles its residual and scan programs once
    obs = analytic_slides(0, 0.05, trajectories, noise=0.002) if observations is None else observations
    return SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.2, 0.0, upper)],
                        weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4,
                        base_params=scene.default_params(sliding_drag=0.0))


def test_no_standard_error_at_a_bound_or_before_convergence(box):
    """Truth 0.45 outside the bounds [0, 0.3]: the estimate sits at 0.3 with a warning and no
    standard error; stopped after one evaluation: no standard errors; a fit much worse than
    the stated noise is flagged."""
    problem = slide_problem(box, upper=0.3)
    res = identify(problem, noise_rms=2e-3)
    assert abs(res.estimates[0] - 0.3) < 1e-6 and np.isnan(res.standard_errors[0])
    assert any("sits at its upper bound" in w for w in res.warnings)
    assert any("stated noise" in w for w in res.warnings)  # the bound keeps it from the data
    res = identify(problem, max_iterations=1, scan=0, profile_points=0)  # one local solve, stopped early
    assert not res.success and np.all(np.isnan(res.standard_errors))
    assert any("evaluation limit" in w for w in res.warnings)
    inside = identify(slide_problem(box), noise_rms=2e-3)
    assert inside.success and np.all(np.isfinite(inside.standard_errors)) and not inside.warnings
    assert inside.as_dict()["warnings"] == []
    with pytest.raises(DanoError, match="noise_rms"):
        identify(problem, noise_rms=-1.0)


def test_disagreeing_local_minima_are_reported(box):
    """Two starts ending at costs within 5 % but at estimates many standard errors apart, and
    a scan that saw a lower cost than any fit: both are warned about."""
    problem = slide_problem(box)

    def result(mu, cost, se=0.001):
        return SysIdResult(labels=["sliding_friction"], estimates=np.array([mu]), standard_errors=np.array([se]),
                           initial=np.array([0.2]), cost_history=[cost], final_cost=cost, rms_residual=0.0,
                           num_residuals=10, nfev=1, njev=1, wall_time_s=0.0, compile_time_s=0.0, success=True,
                           message="", jacobian="ad")

    best, other, far_worse = result(0.40, 1.00), result(0.45, 1.03), result(0.9, 2.0)
    notes = _disagreement(problem, best, [best, other, far_worse], scan_best=1.2)
    assert len(notes) == 1 and "local minima" in notes[0] and "0.4..0.45" in notes[0]
    notes = _disagreement(problem, best, [best, result(0.4005, 1.0)], scan_best=0.9)
    assert len(notes) == 1 and "scan saw a lower cost" in notes[0]


@pytest.mark.slow  # many seeds: 12 s
def test_bootstrap_over_trajectories_covers_the_truth_in_most_seeds():
    """Analytic Coulomb slides (μ = 0.45, not simulated by dano), 8 per data set, 3 mm noise
    in every frame including the first (so each trajectory carries its own offset): the
    bootstrap's 95 % interval covers the truth in at least 2 of 3 seeds (20 seeds: see
    docs/sysid.md)."""
    r = bootstrap_coverage(seeds=3, samples=30)
    assert r["bootstrap_covers"] >= 2, r
    for s in r["per_seed"]:
        assert s["lower"] < s["estimate"] < s["upper"] and s["bootstrap_std"] > 0


def test_bootstrap_needs_two_trajectories(box):
    problem = slide_problem(box, trajectories=1)
    with pytest.raises(DanoError, match="at least two"):
        bootstrap(problem, np.array([0.45]))
    with pytest.raises(DanoError, match="level"):
        bootstrap(slide_problem(box), np.array([0.45]), level=1.5)
    obs = Observation(time=np.arange(5) * 0.01, poses={"box": np.tile([0, 0, 0.05, 1, 0, 0, 0.0], (5, 1))})
    assert SysIdProblem(box, [obs, obs], [FitParameter("sliding_friction", 0.3, 0, 1)], substeps=4
                        ).residual_observations().tolist() == [0] * 24 + [1] * 24


def test_bootstrap_leaves_out_refits_stopped_at_the_evaluation_limit(box):
    """A refit that stops at its evaluation limit, even after a second try from where it
    stopped, is left out and counted: it sits between the estimate and its own minimum and
    would narrow the spread. With one evaluation per try none converges: refused, saying so;
    with the default limit every refit converges and none is left out."""
    problem = slide_problem(box)
    with pytest.raises(DanoError, match="still at the evaluation limit"):
        bootstrap(problem, np.array([0.3]), samples=3, max_iterations=1)
    b = bootstrap(problem, np.array([0.45]), samples=3)
    assert b["unconverged"] == 0 and b["failed"] == 0 and len(b["estimates"]) == 3


def _without(obs: Observation, frames) -> Observation:
    keep = np.ones(obs.num_frames, dtype=bool)
    keep[list(frames)] = False
    return dataclasses.replace(obs, time=obs.time[keep], poses={k: v[keep] for k, v in obs.poses.items()})


def test_missing_frames_split_the_rollouts_and_keep_the_answer(box):
    """Analytic Coulomb slides (μ = 0.45, not simulated by dano) with frames dropped as a
    camera drops them: each run of consecutive frames is rolled out from its own first frame
    (a run of two frames is left out), a note says so, the start velocities those runs
    difference from noisy frames are fitted (fit_velocity "auto"), and the estimate stays
    inside the full data's interval."""
    full = slide_problem(box)
    obs = list(full.observations)
    obs[0], obs[1] = _without(obs[0], [6, 13, 14]), _without(obs[1], [2])
    gapped = slide_problem(box, observations=obs)
    # the runs after a gap start from differenced velocities of 2 mm frames: fitted (auto)
    assert full.fit_velocity == "" and gapped.fit_velocity == "xy"
    assert obs[0].runs() == ((0, 6), (6, 6), (12, 5)) and obs[1].runs() == ((0, 2), (2, 17))
    assert [(s.start, s.frames) for s in gapped.segments if s.obs < 2] == [(0, 6), (6, 6), (12, 5), (2, 17)]
    notes = [n for n in gapped.notes if "missing" in n]
    assert len(notes) == 2 and "slide_0: 3 frames missing (after t = 0.05, 0.12 s)" in notes[0]
    assert "slide_1: 1 frame missing" in notes[1] and "left out (frames 0-1)" in notes[1]
    assert len([n for n in dataclasses.replace(gapped, window=None).notes if "missing" in n]) == 2  # not twice
    a, b = identify(full), identify(gapped)
    lo, hi = a.interval["lower"]["sliding_friction"], a.interval["upper"]["sliding_friction"]
    assert lo < b.estimates[0] < hi, (a.estimates, b.estimates, lo, hi)
    assert any("missing" in n for n in b.notes)


def test_jittered_time_stamps_are_compared_at_their_own_times(box):
    """Analytic Coulomb slides (μ = 0.45, the closed form, not simulated by dano) observed at
    time stamps that jitter by up to ±2 ms around 10 ms frames: each frame is compared with the
    rollout interpolated to its own time (a note says so), so the fit is as close as at exact
    time stamps and the estimate the same; the same frames with their times put on the grid
    leave the jitter in the residual."""
    rng = np.random.default_rng(3)
    exact = analytic_slides(0, 0.05, 8, noise=0.0)

    def observed(o, t):  # the closed form s(t) = v0 t - mu g t^2 / 2 along the slide's heading
        v0 = o.qvel0[:2]
        s = np.linalg.norm(v0) * t - 0.5 * 0.45 * 9.81 * t**2
        poses = np.zeros((len(t), 7))
        poses[:, :2], poses[:, 2], poses[:, 3] = np.outer(s, v0 / np.linalg.norm(v0)), 0.05, 1.0
        return {"box": poses}

    jittered, on_grid = [], []
    for o in exact:
        t = o.time + np.r_[0.0, rng.uniform(-0.002, 0.002, o.num_frames - 1)]
        jittered.append(dataclasses.replace(o, time=t, poses=observed(o, t)))
        on_grid.append(dataclasses.replace(o, poses=observed(o, t)))
    problem = slide_problem(box, observations=jittered)
    notes = [n for n in problem.notes if "interpolated to its own time" in n]
    assert len(notes) == 8 and "slide_0: time stamps off the frame rate by up to" in notes[0]
    a, b, c = identify(slide_problem(box, observations=exact)), identify(problem), identify(
        slide_problem(box, observations=on_grid))
    assert abs(b.estimates[0] - a.estimates[0]) < 0.005 and abs(b.estimates[0] - 0.45) < 0.02, (a.estimates,
                                                                                              b.estimates)
    assert b.rms_residual < 2 * a.rms_residual + 1e-4 and c.rms_residual > 5 * b.rms_residual, (
        a.rms_residual, b.rms_residual, c.rms_residual)


def test_states_at_jittered_frames_are_interpolated_between_steps():
    """A rollout's states at frames that fall between its steps: positions linear in time, the
    orientation's quaternion renormalised (a body turning at 2 rad/s about z, steps of 2.5 ms:
    within the chord's error of the exact turn); frames on the grid are the steps themselves."""
    from dano.sysid.problem import _at_frames, frame_shifts

    h, substeps, w = 0.0025, 4, 2.0
    steps = np.arange(41) * h
    qpos = np.zeros((41, 7))
    qpos[:, 0], qpos[:, 3], qpos[:, 6] = 1.5 * steps, np.cos(w * steps / 2), np.sin(w * steps / 2)
    t = np.array([0.0, 0.0113, 0.0191, 0.0304, 0.0401])  # 10 ms frames, up to 1.3 ms off
    shift = frame_shifts(t, substeps * h, substeps)
    assert np.allclose(shift, [0, 0.52, -0.36, 0.16, 0.04])
    out = np.asarray(_at_frames(jnp.asarray(qpos), 0, substeps, 5, jnp.asarray(shift), (3,)))
    assert np.allclose(out[:, 0], 1.5 * t, atol=1e-12)
    assert np.allclose(np.linalg.norm(out[:, 3:], axis=1), 1.0)
    exact = np.c_[np.cos(w * t / 2), np.zeros((5, 2)), np.sin(w * t / 2)]
    assert np.abs(out[:, 3:] - exact).max() < 1e-5  # (the chord: (w h)^2 / 32 at most)
    assert np.array_equal(np.asarray(_at_frames(jnp.asarray(qpos), 2, substeps, 5)), qpos[2:19:4])


def test_noise_of_jittered_frames_is_not_their_motion():
    """The noise estimated from frames whose time stamps jitter (±2 ms around 10 ms frames, a
    body moving at 1.5 m/s and turning at 1 rad/s, 1 mm of noise): divided differences at the
    frames' own times find the 1 mm and no rotation noise; plain differences, as if the frames
    were evenly spaced, count the motion between uneven frames as noise."""
    from dano.sysid.uncertainty import noise_of_observations

    rng = np.random.default_rng(0)
    t = np.arange(200) * 0.01
    t_jittered = t + np.r_[0.0, rng.uniform(-0.002, 0.002, 199)]
    poses = np.zeros((200, 7))
    poses[:, 0], poses[:, 1] = 1.5 * t_jittered, 0.3 * t_jittered
    poses[:, 3], poses[:, 6] = np.cos(t_jittered / 2), np.sin(t_jittered / 2)
    poses[:, :3] += rng.normal(0.0, 0.001, (200, 3))
    jittered = noise_of_observations([Observation(time=t_jittered, poses={"box": poses}, frame_interval=0.01)])
    as_even = noise_of_observations([Observation(time=t, poses={"box": poses})])
    assert np.all((np.asarray(jittered["position_m"]) > 0.0007) & (np.asarray(jittered["position_m"]) < 0.0013))
    assert jittered["rotation_deg"] < 1e-6 and as_even["rotation_deg"] > 0.01
    assert as_even["position_m"][0] > 1.8 * jittered["position_m"][0]


def test_missing_frames_refused_where_they_cannot_be(box):
    """Frames shifted off the frame rate's grid by more than jitter, a gap too long for
    dropped frames, no three consecutive frames, rest frames past the first gap, a frame
    interval longer than the frames' and time stamps that jitter around another frame rate
    than the simulation's are refused, each saying why."""
    o = slide_problem(box, trajectories=2).observations[0]
    param = [FitParameter("sliding_friction", 0.3, 0, 1)]
    shifted = dataclasses.replace(o, time=o.time + np.r_[np.zeros(5), np.full(15, 0.004)])
    cases = [(shifted, "is farther from its place at that rate"),
             (dataclasses.replace(o, time=o.time + np.r_[np.zeros(19), 100.0]), "more than 1000 frames missing"),
             (_without(o, [2, 4, 6, 8, 10, 12, 14, 16, 18]), "no 3 consecutive frames"),
             (dataclasses.replace(_without(o, [3]), rest_frames=4), "rest_frames = 4"),
             (dataclasses.replace(o, frame_interval=0.02), "frames \\d+ and \\d+ \\(t = [0-9.]+ s\\) are 0.01 s apart, no more than half "
              "the frame interval, 0.02 s"),
             (dataclasses.replace(o, frame_interval=-0.01), "frame_interval must be positive, got -0.01"),
             # time stamps that jitter around 20 ms frames for a simulation of 10 ms ones
             (dataclasses.replace(o, time=o.time * 2 + np.r_[0.0, np.full(19, 0.001)]),
              "jitter around a frame interval of about 0.02 s .*for 4 substeps, dt about 0.005 s"),
             # every other frame missing: the given frame interval keeps them missing, not a slower rate
             (dataclasses.replace(_without(o, range(1, 20, 2)), frame_interval=0.01), "no 3 consecutive frames")]
    for bad, message in cases:
        with pytest.raises(DanoError, match=message):
            SysIdProblem(box, [bad], param, substeps=4)


def _clean_slides(noise: float, seed: int = 0, trajectories: int = 2) -> list:
    """Analytic slides whose first frame is exact and later frames carry ``noise`` [m] (x, y)."""
    rng = np.random.default_rng(seed)
    obs = analytic_slides(0, 0.05, trajectories, noise=0.0)
    for o in obs:
        o.poses["box"][1:, :2] += rng.normal(0.0, noise, (len(o.time) - 1, 2))
    return obs


def test_residual_noise_follows_the_residual_layout_and_gives_the_cramer_rao_bound(box):
    """residual_noise scales each residual's noise like the residual itself (checked entry by
    entry against the residuals that move when one trajectory's y positions move), and the
    Cramér–Rao bound at the truth agrees with the standard error a fit to noisy data reports."""
    weights = Weights((1.0, 4.0, 0.0), 9.0)
    clean = _clean_slides(0.0)
    problem = SysIdProblem(box, clean, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], weights=weights,
                           substeps=4, base_params=box.default_params(sliding_drag=0.0))
    sd = problem.residual_noise(1e-3, 0.5)
    assert sd.shape == (problem.num_residuals,)
    assert set(np.round(sd, 12)) == {1e-3, 2e-3, round(3 * np.radians(0.5) / np.sqrt(3), 12)}
    moved = [dataclasses.replace(o, poses={"box": o.poses["box"] + (k == 1) * np.r_[0, 1e-3, 0, 0, 0, 0, 0]})
             for k, o in enumerate(clean)]
    moved[1].poses["box"][0, 1] -= 1e-3  # the first frame (the initial state) stays
    shifted = SysIdProblem(box, moved, problem.parameters, weights=weights, substeps=4,
                           base_params=problem.base_params)
    theta = np.array([0.45])
    diff = np.asarray(shifted.residual_function()(theta)) - np.asarray(problem.residual_function()(theta))
    changed = np.abs(diff) > 1e-9
    assert np.array_equal(changed, np.isclose(sd, 2e-3) & (problem.residual_observations() == 1))
    np.testing.assert_allclose(diff[changed], -2e-3, rtol=1e-9)  # -√w_y · 1 mm
    # the bound at the truth vs a fit's σ²(JᵀJ)⁻¹ on data with that noise
    noisy = SysIdProblem(box, _clean_slides(3e-3, seed=1, trajectories=8),  # (slide_problem's structure)
                         [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], weights=Weights((1.0, 1.0, 0.0), 0.0),
                         substeps=4, base_params=problem.base_params)
    fit = identify(noisy)
    bound = np.sqrt(cramer_rao(noisy, theta, noisy.residual_noise(3e-3, 0.0))[0, 0])
    assert 0.7 < fit.standard_errors[0] / bound < 1.4, (fit.standard_errors[0], bound)
    assert abs(fit.estimates[0] - 0.45) < 4 * bound
    with pytest.raises(DanoError, match="theta"):
        cramer_rao(noisy, np.array([0.45, 1.0]), 3e-3)
    with pytest.raises(DanoError, match="noise"):
        cramer_rao(noisy, theta, 0.0)
    with pytest.raises(DanoError, match="noise level"):
        noisy.residual_noise(-1e-3, 0.0)


def test_the_residual_says_where_a_misfit_lies(box):
    """residual_kinds labels each residual as residual_noise lays them out (positions, then the
    rotation vector, per frame), and residual_shares splits ‖r‖² by kind: slides whose observed
    rotations turn where the model's do not leave their misfit in the rotations, and the misfit
    warning then says so, with what the problem could still do about a spin."""
    from dano.sysid.solve import _misfit_warning, _spin_remedies, residual_shares

    weights = Weights((1.0, 4.0, 0.0), 9.0)
    clean = _clean_slides(0.0)
    problem = SysIdProblem(box, clean, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], weights=weights,
                           substeps=4, base_params=box.default_params(sliding_drag=0.0))
    kinds = problem.residual_kinds()
    sd = problem.residual_noise(1e-3, 0.5)
    assert kinds.shape == (problem.num_residuals,) and set(kinds) == {"position", "rotation"}
    assert np.array_equal(kinds == "position", np.isclose(sd, 1e-3) | np.isclose(sd, 2e-3))
    theta = np.array([0.45])  # the truth: the residual is rounding
    turned = []
    for o in clean:  # each observed pose after the first turned about z by 0.2 rad: the model's do not
        quats = o.poses["box"][:, 3:].copy()
        quats[1:] = [np.cos(0.1) * q + np.sin(0.1) * np.array([-q[3], -q[2], q[1], q[0]]) for q in quats[1:]]
        turned.append(dataclasses.replace(o, poses={"box": np.concatenate([o.poses["box"][:, :3], quats], axis=1)}))
    misfit = SysIdProblem(box, turned, problem.parameters, weights=weights, substeps=4,
                          base_params=problem.base_params)
    r = misfit.residuals(theta)
    shares = residual_shares(misfit, theta)
    assert set(shares) == {"position", "rotation"} and abs(sum(shares.values()) - 1) < 1e-12
    np.testing.assert_allclose(shares["rotation"], r[kinds == "rotation"] @ r[kinds == "rotation"] / (r @ r),
                               rtol=1e-12)
    assert shares["rotation"] > 0.99
    said = _misfit_warning(1e-2, 1e-4, [1e-4] * 3, shares, _spin_remedies(misfit))
    assert "100% in the rotations" in said and "identify torsional_friction too" in said and "per_sample" in said
    assert "in the rotations" not in _misfit_warning(1e-2, 1e-4, [1e-4] * 3, {"position": 1.0})


def test_initial_pose_offsets_are_identified(box):
    """fit_position / fit_rotation: a first frame observed 4 mm and -3 mm off in x, y (one
    slide) and turned 3 degrees about z (the other) is corrected by the nuisance offsets,
    and the friction is the one of the clean data. The square box slides turned by 90° about
    z, so that offsets in its body frame would come out as (-3, -4) mm: they are in the world's.
    Plain least squares (start_prior False) recovers the planted errors; with the start prior
    the start frame counts as one observation more, of the same weight as each later frame:
    a rotation offset, which moves each of the N later frames' residuals alike, comes out as
    the weighted mean, N/(N + 1) of the planted error."""
    obs = _clean_slides(0.0)
    turned = np.radians(90.0)
    for o in obs:
        o.poses["box"][:, 3:] = (np.cos(turned / 2), 0.0, 0.0, np.sin(turned / 2))
    obs[0].poses["box"][0, :2] += (4e-3, -3e-3)
    yaw = np.radians(3.0)
    obs[1].poses["box"][0, 3:] = (np.cos((turned + yaw) / 2), 0.0, 0.0, np.sin((turned + yaw) / 2))
    problem = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                           weights=Weights((1.0, 1.0, 1.0), 1.0), substeps=4, fit_position="xy", fit_rotation="z",
                           base_params=box.default_params(sliding_drag=0.0), start_prior=False)
    assert problem.labels == ["sliding_friction", "p0[0]:box:x", "p0[0]:box:y", "r0[0]:box:z",
                              "p0[1]:box:x", "p0[1]:box:y", "r0[1]:box:z"]
    res = identify(problem)
    est = dict(zip(res.labels, res.estimates))
    assert abs(est["p0[0]:box:x"] + 4e-3) < 3e-4 and abs(est["p0[0]:box:y"] - 3e-3) < 3e-4
    assert abs(est["r0[1]:box:z"] + yaw) < np.radians(0.1)
    assert abs(est["r0[0]:box:z"]) < np.radians(0.1) and abs(est["p0[1]:box:x"]) < 3e-4
    assert abs(est["sliding_friction"] - 0.45) < 0.02
    with_prior = dataclasses.replace(problem, start_prior=True)
    frames = obs[1].num_frames - 1
    assert with_prior.num_residuals == problem.num_residuals + 6  # a row per offset
    # each row carries its frame's noise in the residuals' units (weights 1: the levels themselves)
    sd = with_prior.residual_noise(1e-3, 0.5)[problem.num_residuals:]
    np.testing.assert_allclose(sd, np.tile([1e-3, 1e-3, np.radians(0.5) / np.sqrt(3)], 2), rtol=1e-12)
    # a start pose averaged over 4 rest frames weighs √4 times a frame (its noise σ/2)
    rest = dataclasses.replace(with_prior, observations=[dataclasses.replace(o, rest_frames=4) for o in obs])
    np.testing.assert_allclose(rest.start_prior_rows.weight, 2 * rest.start_prior_rows.unit, rtol=1e-12)
    est = dict(zip(res.labels, identify(with_prior).estimates))
    assert abs(est["r0[1]:box:z"] + yaw * frames / (frames + 1)) < 0.02 * yaw / (frames + 1)
    with pytest.raises(DanoError, match="fit_rotation"):
        SysIdProblem(box, obs, problem.parameters, substeps=4, fit_rotation="zz")


def test_dynamics_recovery_propagates_a_covariance_to_the_principal_moments():
    """The moments are linear in the second-moment scales (I_x = Σ_y + Σ_z, ...): their
    standard deviations follow from the scales' by the delta method, exactly."""
    from dano.sim.dynamics import second_moments
    from dano.experiments.sysid_examples import dynamics_recovery

    base = np.array([3.0, 2.6, 1.5])
    truth = {"alpha": 0.1, "sliding_friction": 0.3, "com_offset": [0.0, 0.0, 0.0], "size": 2.0,
             "principal_moments": base.tolist(), "base_moments": base.tolist()}
    labels = ["bunny:alpha", "bunny/ground:sliding_friction"] + [f"bunny:com_offset_{a}" for a in "xyz"] + [
        f"bunny:second_moment_scale_{a}" for a in "xyz"]
    estimates = dict(zip(labels, [0.1, 0.3, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0]))
    sd = np.array([0.001, 0.003, 0.01, 0.02, 0.04, 0.01, 0.02, 0.03])
    out = dynamics_recovery(estimates, truth, np.diag(sd**2))
    b = second_moments(base)
    expected = np.sqrt([(b[1] * sd[6]) ** 2 + (b[2] * sd[7]) ** 2, (b[0] * sd[5]) ** 2 + (b[2] * sd[7]) ** 2,
                        (b[0] * sd[5]) ** 2 + (b[1] * sd[6]) ** 2]) / base
    np.testing.assert_allclose(out["moment_relative_std"], expected, rtol=1e-12)
    np.testing.assert_allclose(out["com_std_of_size"], [0.005, 0.01, 0.02])
    assert abs(out["alpha_relative_std"] - 0.01) < 1e-12 and abs(out["friction_relative_std"] - 0.01) < 1e-12
    np.testing.assert_allclose(out["moment_relative_error"], 0.0, atol=1e-12)
    assert "moment_relative_std" not in dynamics_recovery(estimates, truth)


def test_misfit_warning_names_a_ratio_only_for_noisy_observations():
    """A fit 10x above the noise's rms residual says so; noise-free observations (third
    differences at rounding) say that the model does not reproduce the motion, not a ratio
    to rounding (a new user saw "1.72e+05x")."""
    from dano.sysid.solve import _misfit_warning

    noisy = _misfit_warning(1e-3, 1e-4, [1e-4, 1e-4, 1e-4])
    assert "misfits" in noisy and "10x" in noisy and "free of noise" not in noisy
    clean = _misfit_warning(1e-3, 5e-12, [5e-12, 1e-12, 0.0])
    assert "misfits" in clean and "free of noise" in clean and "x what" not in clean
    assert len(noisy) < 500 and len(clean) < 500


def test_a_profile_interval_holds_its_estimate_between_grid_points():
    """Noise-free data: a minimum far narrower than the profile's spacing. On the grid alone
    only the nearest value lies within the threshold, and the README's tumbling drop reported
    [0.2954, 0.2954] for its estimate 0.3; the hull now holds the estimate, and where the
    grid's interval holds it already the estimate changes nothing."""
    from dano.sysid.uncertainty import profile_interval

    values = np.linspace(0.157, 0.443, 32)
    narrow = 1e4 * (values - 0.3) ** 2
    lower, upper, _, _ = profile_interval(values, narrow, 1e-20)
    assert not lower <= 0.3 <= upper  # the grid alone: beside the estimate
    lower, upper, at_a, at_b = profile_interval(values, narrow, 1e-20, 0.3)
    assert lower <= 0.3 <= upper and upper - lower < values[1] - values[0] and not (at_a or at_b)
    wide = (values - 0.3) ** 2
    assert profile_interval(values, wide, 1e-3, 0.3) == profile_interval(values, wide, 1e-3)
