"""``dano trajopt push``, the push task for any object: its bad input. The task itself runs
in the own-object walkthrough (tests/test_own_object_doc.py: a 0.2 m toy pushed to a goal)."""

import pytest

from dano.cli import main


@pytest.mark.parametrize("args, message", [
    (["push", "--goal", "0.3"], "--goal must be two numbers X,Y"),
    (["push", "--goal", "a,b"], "--goal must be two numbers X,Y"),
    (["push", "--goal", "0,0"], "is where the object starts"),
    (["push", "--object", "missing.dano"], "missing.dano"),
    (["push", "--pusher", "panda"], "pusher out of range"),
    (["push-sphere", "--object", "builtin:bunny"], "push-sphere does not use --object"),
])
def test_push_bad_input(args, message, tmp_path, capsys):
    out = tmp_path / "o"
    assert main(["trajopt", *args, "-o", str(out), "--quiet"]) == 1
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err and not out.exists()


def test_push_programs_are_shared_by_objects_of_one_structure(tmp_path, monkeypatch):
    """Issue 32 item 1: the iLQR's programs of ``push`` serve every object of one structure
    (the scene, its pusher sized to the object and the control scale are the problem's
    parameters, not constants): a ball pushed after a box of as many samples loads the box's
    forward pass, and its plain push from that program equals the one traced for the ball
    alone (a problem without a key: plain jax.jit) bit for bit."""
    import jax.numpy as jnp
    import numpy as np

    import dano
    from dano import _compiled
    from dano.asset import build, save
    from dano.experiments.push import PushObjectConfig, PushParams, push_object_task
    from dano.fields import BoxField, SphereField
    from dano.trajopt import Problem, rollout
    from dano.trajopt.ilqr import _CACHED

    dano.enable_float64()
    files = {"box": tmp_path / "box.dano", "ball": tmp_path / "ball.dano"}
    save(build(BoxField((0.06, 0.04, 0.03)), mass=0.3, num_samples=300, mesh_resolution=0, name="box"), files["box"])
    save(build(SphereField(0.03), mass=0.2, num_samples=300, mesh_resolution=0, name="ball"), files["ball"])
    monkeypatch.delenv("DANO_EXPORT_CACHE", raising=False)
    _compiled.set_directory(tmp_path / "exported")
    try:
        before = _CACHED["forward"].counts["traced"]
        push_object_task(PushObjectConfig(object=str(files["box"]), horizon=20))
        ball = push_object_task(PushObjectConfig(object=str(files["ball"]), horizon=20))
        assert _CACHED["forward"].counts["traced"] - before == 1
    finally:
        _compiled.set_directory(None)
    pr = ball.problem
    alone = Problem(pr.dynamics, pr.stage_cost, pr.terminal_cost, pr.horizon, pr.nx, pr.nu)  # (no key)
    X = rollout(alone, ball.x0, ball.U_plain, PushParams(ball.params, None, ball.scene, jnp.asarray(ball.u_ref)))
    moved = np.ptp(ball.X_plain[:, ball.bunny_qpos][:, 0])
    assert np.all(np.isfinite(ball.X_plain)) and moved > 0.002  # (pushed: 4 mm)
    np.testing.assert_array_equal(np.asarray(X), ball.X_plain)


def test_a_goal_beyond_the_reach_at_rest_is_warned_of_and_the_default_goal_is_within_it():
    """With ``at_rest`` (the default), an object pushed from rest and stopped by friction μ
    alone within the horizon T·h can end at most ½μg(T·h)² away (0.981 m at μ = 0.05 and
    push's 2 s): a goal 5 m away is warned of (a status of infeasible would follow after the
    solve); the default goal of the 1 m bunny (L, L/2) is brought within a quarter of that
    reach."""
    import numpy as np

    from dano.errors import DanoError
    from dano.experiments.push import PushObjectConfig, push_object_task, reach_warnings, stopping_reach

    config = PushObjectConfig(goal=(5.0, 0.0))
    assert stopping_reach(config) == pytest.approx(0.5 * 0.05 * 9.81 * 2.0 ** 2)
    far = push_object_task(config)
    (warning,) = reach_warnings(far)
    assert "the goal is 5 m away, beyond the 0.981 m" in warning and "at_rest = false" in warning
    with pytest.raises(DanoError, match="horizon 2 steps of 0.02 s at sliding friction 0.05"):
        push_object_task(PushObjectConfig(horizon=2))
    assert reach_warnings(push_object_task(PushObjectConfig(goal=(5.0, 0.0), at_rest=False))) == []
    default = push_object_task(PushObjectConfig())
    assert np.linalg.norm(default.bunny_goal) == pytest.approx(0.25 * stopping_reach(config))
    assert default.bunny_goal[1] == pytest.approx(0.5 * default.bunny_goal[0]) and reach_warnings(default) == []
    # it starts at rest on the ground: settled, not 1 mm above its lowest sample's touch
    nq = default.scene.nq
    z = default.bunny_qpos.start + 2
    assert np.all(default.x0[nq:] == 0.0) and np.ptp(default.X_plain[:5, z]) < 1e-4


def test_the_pushers_force_is_bounded_in_its_weights():
    """``max_force`` bounds the force on the pusher to that many of its weights m·g: the stage
    inequality (|F|/(m·g))² − max_force² is ≤ 0 within the bound and > 0 beyond it, whatever
    the object; inf leaves only the floor constraint."""
    import numpy as np

    from dano.experiments.push import PushObjectConfig, push_object_task

    task = push_object_task(PushObjectConfig(max_force=0.5))
    p, x = task.problem_params(), task.x0
    weight = float(task.u_ref[0])
    for weights, inside in ((0.25, True), (0.49, True), (0.51, False), (1.0, False)):
        u = np.zeros(6)
        u[:2] = weights * weight / np.sqrt(2.0)  # (along a diagonal: the norm, not each axis)
        floor, force = np.asarray(task.problem.inequality(x, u, 0, p))
        assert (force <= 0) == inside and floor <= 0, (weights, force)  # (the sphere starts on its floor)
    unbounded = push_object_task(PushObjectConfig(max_force=float("inf")))
    assert np.asarray(unbounded.problem.inequality(x, np.full(6, 1e6), 0, unbounded.problem_params())).shape == (1,)
