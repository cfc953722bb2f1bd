"""Built-in scenes run, do what they say, and write trajectories and videos."""

import numpy as np
import pytest

from dano.sim import load_trajectory, rollout, save_trajectory
from dano.sim.scenes import BUILTIN_SCENES, load_scene


@pytest.fixture
def menagerie(shared, monkeypatch):
    monkeypatch.setenv("MENAGERIE_ROOT", str(shared / "menagerie"))


def run(name, steps=None):
    s = load_scene(name)
    T = steps or int(round(s.duration / s.scene.dt))
    ctrl = s.controls(np.arange(T) * s.scene.dt) if s.controls else None
    return s, rollout(s.scene, s.state0, ctrl, s.params, T)


# the bunny drop runs as many steps as the bunny slide's 2.5 s: the same structure (the bunny
# on the ground, 0.01 s), so one compiled rollout serves the three tests
SLIDE_STEPS = 250


def sliding_distance(v0, mu, drag, g=9.81):
    """Stopping distance under Coulomb friction μ and the paper's viscous drag scaled by the
    normal force m·g (Eq. 9): dv/dt = −g(μ + drag·v), so x = (v0 − (μ/drag)·ln(1 + drag·v0/μ))/(g·drag)."""
    if drag == 0:
        return v0**2 / (2 * mu * g)
    return (v0 - mu / drag * np.log1p(drag * v0 / mu)) / (g * drag)


def test_bunny_slide_stops_at_the_coulomb_and_drag_distance():
    s, traj = run("bunny-slide")
    assert len(traj.time) == SLIDE_STEPS + 1  # its 2.5 s
    p = s.params.contact
    expected = sliding_distance(2.5, float(p.sliding_friction[0]), float(p.sliding_drag[0]))
    assert float(p.sliding_drag[0]) == 0.1  # the paper's default drag, which now acts
    assert abs(traj.qpos[-1, 0] / expected - 1) < 0.03
    assert np.linalg.norm(traj.qvel[-1, :3]) < 1e-2


def test_sphere_hits_bunny_pushes_it():
    s, traj = run("sphere-hits-bunny", 120)
    bunny, _ = traj.dano_pose("bunny")
    assert traj.psi[:, s.scene.pair_names.index("bunny/sphere")].max() > 0
    assert bunny[-1, 0] > 0.3


def test_two_bunnies_touch_each_other():
    s, traj = run("two-bunnies-sphere", 150)
    k = s.scene.pair_names.index("bunny_a/bunny_b")
    assert traj.psi[:, k].max() > 1e-4
    b, _ = traj.dano_pose("bunny_b")
    assert b[-1, 0] - b[0, 0] > 0.1  # the second bunny was pushed by the first


def test_panda_pushes_bunny(menagerie):
    s, traj = run("panda-push-bunny")
    b, _ = traj.dano_pose("bunny")
    assert traj.psi[:, s.scene.pair_names.index("bunny/pusher")].max() > 0
    # the pusher bar sweeps x = 0.30 ... 0.75 at bunny height and stops; the bunny (15 cm) is
    # carried ahead of it (with the paper's drag it barely slides on after the push)
    assert b[-1, 0] - b[0, 0] > 0.15
    assert abs(b[-1, 2] - b[0, 2]) < 0.02  # still on the ground


def test_panda_without_menagerie_is_a_clear_error(monkeypatch):
    monkeypatch.delenv("MENAGERIE_ROOT", raising=False)
    from dano.errors import DanoError

    with pytest.raises(DanoError, match="MENAGERIE_ROOT"):
        load_scene("panda-push-bunny")


def test_trajectory_file_round_trip(tmp_path):
    s, traj = run("bunny-drop", SLIDE_STEPS)
    path = save_trajectory(traj, tmp_path / "t.npz")
    z = np.load(path)
    assert z["time"].shape == (251,) and z["qpos"].shape == (251, 7) and z["qvel"].shape == (251, 6)
    assert "bunny" in z["body_names"].tolist()
    back = load_trajectory(path)
    np.testing.assert_array_equal(back.qpos, traj.qpos)
    assert back.dano_names == ("bunny",) and back.pair_names == ("bunny/ground",)


def test_video_is_written(tmp_path):
    import imageio.v2 as imageio

    from dano.viz.video import write_video

    s, traj = run("bunny-drop", SLIDE_STEPS)
    path = write_video(s.scene, traj, tmp_path / "drop.mp4", fps=20, width=160, height=120)
    reader = imageio.get_reader(path)
    n = sum(1 for _ in reader)
    assert n == int(2.5 * 20) + 1
    assert [p.name for p in tmp_path.iterdir()] == ["drop.mp4"]


def test_all_builtins_are_listed():
    assert set(BUILTIN_SCENES) == {"bunny-drop", "bunny-slide", "sphere-hits-bunny", "two-bunnies-sphere",
                                   "panda-push-bunny"}
