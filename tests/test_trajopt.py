"""Trajectory optimisation: the constrained iLQR against analytic LQR, a pendulum swing-up,
infeasible constraints, receding horizon under model error, the linearisation of the
contact dynamics against finite differences, and the paper's push-sphere task end to end."""

import dataclasses
import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano.cli import main
from dano.errors import DanoError
from dano.trajopt import Options, Problem, quadratic_problem, rollout, solve
from dano.trajopt.ilqr import _compiled
from dano.trajopt.mpc import receding_horizon


def _batch_lqr(A, B, Q, R, Qf, x0, T):
    """The finite-horizon LQR optimum as one least-squares problem over the stacked
    controls (no Riccati recursion): X = Φx0 + ΓU, minimise ½XᵀQ̄X + ½UᵀR̄U."""
    nx, nu = B.shape
    Phi = np.vstack([np.linalg.matrix_power(A, t) for t in range(T + 1)])
    Gam = np.zeros(((T + 1) * nx, T * nu))
    for t in range(T + 1):
        for s in range(t):
            Gam[t * nx:(t + 1) * nx, s * nu:(s + 1) * nu] = np.linalg.matrix_power(A, t - 1 - s) @ B
    Qb = np.kron(np.eye(T + 1), Q)
    Qb[-nx:, -nx:] = Qf
    Rb = np.kron(np.eye(T), R)
    return -np.linalg.solve(Gam.T @ Qb @ Gam + Rb, Gam.T @ Qb @ Phi @ x0).reshape(T, nu)


def test_first_iteration_is_the_analytic_lqr_solution():
    rng = np.random.default_rng(0)
    nx, nu, T = 4, 2, 20
    A = np.eye(nx) + 0.1 * rng.normal(size=(nx, nx))
    B = rng.normal(size=(nx, nu))
    Q, R, Qf = np.diag(rng.uniform(0.5, 2, nx)), np.diag(rng.uniform(0.1, 1, nu)), 10 * np.eye(nx)
    pr = quadratic_problem(lambda x, u, t, p: jnp.asarray(A) @ x + jnp.asarray(B) @ u, Q, R, Qf, T, nx, nu)
    x0 = rng.normal(size=nx)
    sol = solve(pr, x0, np.zeros((T, nu)), options=Options(max_iterations=1))
    assert sol.iterations == 1 and sol.log["step"][0] == 1.0
    np.testing.assert_allclose(np.asarray(sol.controls), _batch_lqr(A, B, Q, R, Qf, x0, T), atol=1e-10)
    # and the states are the dynamics' rollout of those controls
    np.testing.assert_allclose(np.asarray(sol.states), np.asarray(rollout(pr, x0, sol.controls)), atol=1e-12)


def test_expansion_in_batches_equals_one_stage_at_a_time(monkeypatch):
    """The expansion linearises the stages one at a time on the CPU and in vmapped batches of
    16 elsewhere (dano.trajopt.ilqr.STAGE_BATCH / ACCELERATOR_STAGE_BATCH), the horizon padded
    where 16 does not divide it: both give the same linearisation, constraint terms included."""
    from dano.trajopt import ilqr

    T = 37  # 3 batches of 13 with 2 padded stages
    pr = _swing_up(5.0, T)
    fns = _compiled(pr)
    rng = np.random.default_rng(1)
    X, U = jnp.asarray(rng.normal(size=(T + 1, 2))), jnp.asarray(rng.normal(size=(T, 1)))
    lam = ilqr.Multipliers(*(jnp.asarray(rng.uniform(0.0, 1.0, s)) for s in fns.sizes(X[0], U, None)))
    out = {}
    for batch in (1, 16):
        monkeypatch.setattr(ilqr, "STAGE_BATCH", batch)
        expand = lambda *a: fns.raw["expand"](*a)  # noqa: E731 - a new function: traced again, reading STAGE_BATCH
        out[batch] = jax.jit(expand)(X, U, lam, jnp.asarray(10.0), None)
    for one, batched in zip(out[1], out[16]):
        assert one.shape == batched.shape
        np.testing.assert_allclose(np.asarray(one), np.asarray(batched), rtol=1e-12, atol=1e-12)


H = 0.05


def _pendulum(x, u, t, p):
    """θ'' = −(g/l)·sin θ − b·θ' + u (semi-implicit Euler, h = 0.05 s); p scales gravity."""
    g = 9.81 if p is None else p
    th, w = x
    w2 = w + H * (-g * jnp.sin(th) - 0.1 * w + u[0])
    return jnp.stack([th + H * w2, w2])


def _swing_up(u_max: float, T: int) -> Problem:
    return Problem(_pendulum, lambda x, u, t, p: 0.005 * jnp.sum(x**2) + 0.05 * jnp.sum(u**2), lambda x, p: 0.0,
                   T, 2, 1, terminal_equality=lambda x, p: x - jnp.array([jnp.pi, 0.0]),
                   u_lower=np.array([-u_max]), u_upper=np.array([u_max]))


def test_pendulum_swing_up_converges_within_torque_limits():
    pr = _swing_up(5.0, 100)  # 5 < g: it must pump energy over several swings
    sol = solve(pr, np.zeros(2), np.zeros((100, 1)))
    assert sol.converged and sol.status == "converged", sol.status
    assert np.abs(np.asarray(sol.states[-1]) - [np.pi, 0]).max() < 1e-4
    assert np.abs(np.asarray(sol.controls)).max() <= 5.0 + 1e-4  # bounds hold to the constraint tolerance
    assert np.abs(np.asarray(sol.controls)).max() > 3.0  # and are used
    assert np.all(np.diff(sol.log["iteration"]) == 1) and len(sol.log["cost"]) == sol.iterations


def test_infeasible_constraints_are_reported_not_looped_on():
    pr = _swing_up(0.05, 60)  # far too weak to lift the pendulum in 3 s
    sol = solve(pr, np.zeros(2), np.zeros((60, 1)), options=Options(max_iterations=500))
    assert sol.status == "infeasible" and not sol.converged
    assert sol.iterations < 100 and sol.max_violation > 1.0


def test_warm_start_from_a_converged_solution_reports_converged():
    """Re-solving from a converged plan: with its multipliers and penalty it is done in one
    iteration; from its controls alone the augmented Lagrangian first leaves the constraints
    (zero multipliers) and comes back, steadily (×7 less violation per round): converged
    (this was reported "infeasible", the rounds being compared with the feasible start)."""
    pr = _swing_up(5.0, 100)
    sol = solve(pr, np.zeros(2), np.zeros((100, 1)))
    again = solve(pr, np.zeros(2), sol.controls, multipliers=sol.multipliers, penalty=sol.penalty)
    assert again.status == "converged" and again.iterations <= 2 and again.cost == pytest.approx(sol.cost, rel=1e-3)
    controls_only = solve(pr, np.zeros(2), sol.controls)
    assert controls_only.status == "converged" and controls_only.max_violation <= 1e-4, controls_only.log
    assert controls_only.cost == pytest.approx(sol.cost, rel=1e-2)


def test_keyed_problems_share_exported_programs(tmp_path):
    """A problem with a key keeps its solver programs on disk (dano._compiled): another
    problem object with an equal key reuses them, bounds that differ (added to the key by the
    solver) or another key trace anew; the answers are those of the unkeyed problem."""
    from dano import _compiled
    from dano.trajopt.ilqr import _CACHED

    def swing(u_max, key):
        return dataclasses.replace(_swing_up(u_max, 40), key=key)

    _compiled.set_directory(tmp_path)
    try:
        forward = _CACHED["forward"]
        before = forward.counts.copy()
        plain = solve(_swing_up(8.0, 40), np.zeros(2), np.zeros((40, 1)))
        assert forward.counts == before  # no key: plain jax.jit
        first = solve(swing(8.0, ("pendulum", 1)), np.zeros(2), np.zeros((40, 1)))
        assert forward.counts["traced"] == before["traced"] + 1
        again = solve(swing(8.0, ("pendulum", 1)), np.zeros(2), np.zeros((40, 1)))
        assert forward.counts["traced"] == before["traced"] + 1 and forward.counts["reused"] > before["reused"]
        solve(swing(7.0, ("pendulum", 1)), np.zeros(2), np.zeros((40, 1)))  # other bounds: other programs
        solve(swing(8.0, ("pendulum", 2)), np.zeros(2), np.zeros((40, 1)))
        assert forward.counts["traced"] == before["traced"] + 3
        assert len(list(tmp_path.glob("*.jaxexp"))) >= 3
    finally:
        _compiled.set_directory(None)
    for sol in (first, again):
        assert sol.status == plain.status and sol.iterations == plain.iterations
        np.testing.assert_allclose(np.asarray(sol.controls), np.asarray(plain.controls), rtol=1e-9, atol=1e-12)


def test_receding_horizon_recovers_from_model_error():
    pr = _swing_up(8.0, 60)
    plan = solve(pr, np.zeros(2), np.zeros((60, 1)), 9.81)
    assert plan.converged
    world = jax.jit(lambda x, u: _pendulum(x, u, 0, 9.81 * 1.15))  # gravity 15 % stronger than modelled
    open_loop = np.asarray(rollout(pr, np.zeros(2), plan.controls, 9.81 * 1.15))
    rh = receding_horizon(pr, np.zeros(2), world, plan.controls, 9.81, every=5, first=plan)
    err_open = np.abs(open_loop[-1] - [np.pi, 0]).max()
    err_rh = np.abs(rh.states[-1] - [np.pi, 0]).max()
    assert err_open > 0.1 and err_rh < 0.01 * err_open, (err_open, err_rh)
    assert rh.states.shape == (61, 2) and rh.controls.shape == (60, 1) and rh.replan_steps == tuple(range(0, 60, 5))


def test_bad_inputs_are_refused():
    pr = _swing_up(5.0, 10)
    with pytest.raises(DanoError, match="x0 must have shape"):
        solve(pr, np.zeros(3), np.zeros((10, 1)))
    with pytest.raises(DanoError, match="initial controls must have shape"):
        solve(pr, np.zeros(2), np.zeros((9, 1)))
    with pytest.raises(DanoError, match="finite"):
        solve(pr, np.array([np.nan, 0.0]), np.zeros((10, 1)))
    with pytest.raises(DanoError, match="u_lower exceeds u_upper"):
        Problem(_pendulum, lambda x, u, t, p: 0.0, lambda x, p: 0.0, 10, 2, 1, u_lower=[1.0], u_upper=[0.0])
    with pytest.raises(DanoError, match="horizon"):
        Problem(_pendulum, lambda x, u, t, p: 0.0, lambda x, p: 0.0, 0, 2, 1)
    with pytest.raises(DanoError, match="every"):
        receding_horizon(pr, np.zeros(2), lambda x, u: x, np.zeros((10, 1)), every=0)
    # a problem's own functions of the wrong shape: dano's error naming the function, not JAX's from inside a scan
    cost = lambda x, u, t, p: jnp.sum(u ** 2)  # noqa: E731
    for bad, message in (
            (Problem(lambda x, u, t, p: jnp.zeros(5), cost, lambda x, p: 0.0, 10, 2, 1),
             r"dynamics\(x, u, t, p\) must return the next state, shape \(2,\), got \(5,\)"),
            (Problem(_pendulum, lambda x, u, t, p: u ** 2, lambda x, p: 0.0, 10, 2, 1),
             r"stage_cost\(x, u, t, p\) must return a scalar, got shape \(1,\)"),
            (Problem(_pendulum, cost, lambda x, p: x, 10, 2, 1), r"terminal_cost\(x, p\) must return a scalar"),
            (Problem(_pendulum, cost, lambda x, p: 0.0, 10, 2, 1, terminal_equality=lambda x, p: x[0]),
             "terminal_equality must return a 1-D array")):
        with pytest.raises(DanoError, match=message):
            solve(bad, np.zeros(2), np.zeros((10, 1)))


@pytest.fixture(scope="module")
def push_task():
    from dano.experiments.push import PushSphereConfig, push_sphere_task

    return push_sphere_task(PushSphereConfig())


@pytest.mark.slow
def test_contact_linearisation_matches_central_differences(push_task):
    """The solver's A_t, B_t (forward-mode AD of dano.sim.step, vmapped over the horizon)
    against central differences of the step in float64, at stages of the plain push with
    the sphere touching the bunny and with it free, away from contact onsets."""
    task = push_task
    pr, p = task.problem, task.problem_params()  # (p: PushParams, the goal and the scene parameters)
    X = np.asarray(rollout(pr, task.x0, task.U_plain, p))
    fns = _compiled(pr)
    from dano.trajopt.ilqr import Multipliers

    lam = Multipliers(*(jnp.zeros(s) for s in fns.sizes(jnp.asarray(task.x0), jnp.asarray(task.U_plain), p)))
    # (the penalty in the solver's dtype, as solve passes it: the CLI test's solve then reuses this expansion)
    mu = jnp.asarray(1.0, X.dtype)
    F = np.asarray(fns.expand(jnp.asarray(X), jnp.asarray(task.U_plain), lam, mu, p)[0])
    step = jax.jit(lambda z: pr.dynamics(z[:pr.nx], z[pr.nx:], 0, p))
    from dano.sim import overlaps

    psi = np.asarray(jax.jit(jax.vmap(lambda x: overlaps(task.scene, task.params, _data(task, x))))(X[:-1]))
    pusher_pair = task.scene.pair_names.index("bunny/pusher")
    touching = np.flatnonzero(psi[:, pusher_pair] > 1e-3)
    free = np.flatnonzero(psi[:, pusher_pair] == 0)
    # well inside each phase (contact on for 3 steps before and after)
    inner = [t for t in touching if all(psi[s, pusher_pair] > 1e-3 for s in range(t - 3, t + 4) if 0 <= s < len(psi))]
    stages = [inner[len(inner) // 2], int(free[2])]
    eps = 1e-6  # relative; 1e-4 and 1e-5 see the friction law's kinks, smaller ones roundoff
    for t in stages:
        z = np.r_[X[t], task.U_plain[t]]
        scale = np.maximum(np.abs(z), 1.0)
        cols = []
        for i in range(len(z)):
            dz = np.zeros_like(z)
            dz[i] = eps * scale[i]
            cols.append((np.asarray(step(z + dz)) - np.asarray(step(z - dz))) / (2 * dz[i]))
        fd = np.stack(cols, axis=1)
        err = np.abs(F[t] - fd).max() / max(np.abs(fd).max(), 1.0)
        assert err < 1e-5, (t, err)


def _data(task, x):
    from dano.sim import make_data

    return make_data(task.scene, x[:task.scene.nq], x[task.scene.nq:])


@pytest.mark.slow
def test_push_sphere_cli_reaches_both_goals(tmp_path, capsys, monkeypatch, push_task):
    """The paper's push-and-slide (Fig. 7) through the command line: the bunny ends 1.0 unit
    sideways of the plain push, the sphere at its goal, both within 0.02 (the aim)."""
    from dano.experiments.push import TASKS, PushSphereConfig

    # the command line builds the task with the builder of TASKS; for the default
    # configuration that is the module's task, built by the same builder with the same
    # configuration (its problem's compiled pieces then shared with the test above)
    build, config_cls = TASKS["push-sphere"]
    asked = []

    def cached_build(cfg):
        asked.append(cfg)
        return push_task if cfg == PushSphereConfig() else build(cfg)

    monkeypatch.setitem(TASKS, "push-sphere", (cached_build, config_cls))
    out = tmp_path / "push"
    code = main(["trajopt", "push-sphere", "--json", "--out-dir", str(out), "--quiet"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    assert asked == [PushSphereConfig()]
    rep = json.loads(cap.out)
    for key in ("bunny_final_error", "pusher_final_error", "max_constraint_violation", "iterations", "converged",
                "wall_time_s", "compile_time_s"):
        assert key in rep
    assert rep["converged"] and rep["bunny_final_error"] < 0.02 and rep["pusher_final_error"] < 0.02, rep
    # the floating sphere stays above the floor (its centre at least its radius, 0.25, up, within
    # the constraint tolerance 1e-3): unconstrained, it dipped to 0.105, half through the ground
    assert rep["pusher_below_floor"] < 1e-3, rep
    assert abs(rep["bunny_goal"][1] - rep["plain_push_bunny_final"][1] - 1.0) < 1e-12
    assert rep["plain_push_object_final"] == rep["plain_push_bunny_final"] and rep["object_goal"] == rep["bunny_goal"]
    # the sphere's largest force, in newtons and in its weights (push-sphere's sphere: 10 kg)
    assert rep["pusher_max_force_n"] == pytest.approx(rep["pusher_max_force"] * 10.0 * 9.81, rel=1e-12), rep
    sol = np.load(out / "solution.npz")
    assert sol["controls"].shape == (60, 6) and sol["states"].shape == (61, 26)
    assert sol["qpos"][:, 2].min() > 0.25 - 1e-3  # (the sphere's free joint comes first)
    # the bunny really moved sideways, pushed: it is > 0.9 from where the plain push left it
    assert np.linalg.norm(sol["states"][-1, 7:9] - sol["plain_states"][-1, 7:9]) > 0.9
    log = (out / "log.csv").read_text().splitlines()
    assert log[0].startswith("iteration,") and len(log) == rep["iterations"] + 1
    cfg = json.loads((out / "config.json").read_text())
    assert cfg["task"] == "push-sphere" and cfg["horizon"] == 60
    assert (out / "push-sphere.mp4").stat().st_size > 10_000 and (out / "convergence.png").stat().st_size > 10_000


@pytest.mark.slow
def test_unconverged_sphere_push_is_solved_again_from_a_weaker_push(push_task):
    """A sphere push whose solve does not converge is solved again from the plain push scaled
    by each of RESTART_GUESS_SCALES: the solution kept violates the constraints no more than
    those it replaced, which the report records (here 3 iterations are too few for all)."""
    import dataclasses

    from dano.experiments.push import solve_task
    from dano.experiments.trajopt_run import report

    task = dataclasses.replace(push_task, config=dataclasses.replace(push_task.config, max_iterations=3))
    sol = solve_task(task)
    assert not sol.converged and sol.status == "max_iterations" and sol.iterations == 3
    others = list(sol.restarts)
    assert len(others) == 2 and all(o["status"] == "max_iterations" and o["iterations"] == 3 for o in others)
    assert sol.max_violation <= min(o["max_violation"] for o in others)
    rep = json.loads(json.dumps(report(task, sol)))  # (JSON as the command line writes it)
    guesses = {"plain push", "plain push x0.5", "plain push x0.25"}
    assert rep["restarts"] == others and {o["guess"] for o in others} | {rep["first_guess"]} == guesses


def test_trajopt_cli_bad_input(tmp_path, capsys, monkeypatch):
    with monkeypatch.context() as m:  # no OpenGL for MuJoCo: refused before the solve, not after it
        m.setenv("MUJOCO_GL", "disable")
        code = main(["trajopt", "push-sphere", "--out-dir", str(tmp_path / "o")])
        err = capsys.readouterr().err
        assert code == 1 and "MUJOCO_GL=disable" in err and "--no-video" in err
    code = main(["trajopt", "push-cube"])
    err = capsys.readouterr().err
    assert code == 1 and "unknown task 'push-cube'" in err
    assert all(name in err for name in ("push-sphere", "push-panda", "grasp-panda", "push,"))  # every built-in task
    cfg = tmp_path / "bad.toml"
    cfg.write_text('task = "push-sphere"\nhorizont = 30\n')
    code = main(["trajopt", str(cfg), "--out-dir", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 1 and "unknown key 'horizont'" in err and str(cfg) in err
    cfg.write_text('task = "push-sphere"\nhorizon = 1\n')
    code = main(["trajopt", str(cfg), "--out-dir", str(tmp_path / "o")])
    assert code == 1 and "horizon out of range" in capsys.readouterr().err
    code = main(["trajopt", "push-sphere", "--model-error", "-2", "--out-dir", str(tmp_path / "o")])
    assert code == 1 and "model_error out of range" in capsys.readouterr().err
    assert not (tmp_path / "o").exists()


def test_a_saved_push_config_names_its_object_wherever_it_is_run_from(tmp_path, monkeypatch):
    """The object of ``push`` is kept as an absolute path: given on the command line, against
    the folder it was run in; in a TOML/JSON file, against the file's folder. So the
    config.json a run saves reruns from any folder (it kept "spot.dano" as given, relative)."""
    from dano.experiments.trajopt_run import load_config

    (tmp_path / "runs").mkdir()
    monkeypatch.chdir(tmp_path)
    cfg = load_config("push", object="spot.dano")
    assert cfg.object == str(tmp_path / "spot.dano")
    assert load_config("push").object == "builtin:bunny"
    saved = tmp_path / "runs" / "push.toml"
    saved.write_text('task = "push"\nobject = "../objects/spot.dano"\n')
    monkeypatch.chdir(tmp_path / "runs")
    assert load_config(str(saved.name)).object == str(tmp_path / "objects" / "spot.dano")
    monkeypatch.chdir("/")
    assert load_config(str(saved)).object == str(tmp_path / "objects" / "spot.dano")
    assert load_config(str(saved), object="other.dano").object == "/other.dano"  # (an override: against the folder run in)
