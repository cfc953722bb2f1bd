"""Bad simulation input: clear errors, no NaN results, no partial files."""

import json
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from dano.cli import main
from dano.data import load_builtin
from dano.errors import DanoError, DanoWarning
from dano.sim import DanoObject, SimulationDiverged, State, compose, make_data, rollout, rollout_arrays
from dano.sim.scenes import load_scene


def run(capsys, *args):
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, " ".join(cap.err.split())


def test_unknown_scene(capsys):
    with pytest.raises(DanoError, match="unknown scene 'bunny-fly'; built-in scenes: bunny-drop"):
        load_scene("bunny-fly")
    code, _, err = run(capsys, "simulate", "bunny-fly")
    assert code == 1 and "unknown scene 'bunny-fly'" in err


def test_mjcf_that_does_not_compile(tmp_path, capsys):
    bad = tmp_path / "bad.xml"
    bad.write_text("<mujoco><worldbody><body><geom type='sphere'/></body></worldbody>")  # unclosed
    with pytest.raises(DanoError, match="bad.xml: cannot load MJCF"):
        compose([DanoObject("b", load_builtin("bunny"))], bad)
    code, _, err = run(capsys, "simulate", bad, "--out", tmp_path / "t.npz")
    assert code == 1 and "bad.xml: cannot load MJCF" in err
    assert not (tmp_path / "t.npz").exists()
    wrong = tmp_path / "wrong.xml"
    wrong.write_text("<mujoco><worldbody><geom type='box' size='-1 1 1'/></worldbody></mujoco>")
    with pytest.raises(DanoError, match="wrong.xml"):
        compose([DanoObject("b", load_builtin("bunny"))], wrong)


def test_mjcf_scene_runs_from_the_cli(tmp_path, capsys):
    xml = tmp_path / "table.xml"
    xml.write_text("<mujoco><worldbody><geom name='floor' type='plane' size='0 0 1'/>"
                   "<geom name='block' type='box' size='0.3 0.3 0.1' pos='0 0 0.1'/></worldbody></mujoco>")
    out = tmp_path / "t.npz"
    code, _, err = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.8", "--duration", 0.3,
                       "--out", out, "--quiet")
    assert code == 0, err
    z = np.load(out)
    assert z["qpos"].shape == (31, 7) and list(z["pair_names"]) == ["bunny/floor", "bunny/block"]
    assert json.loads(str(z["metadata"]))["scene"] == "table"


@pytest.mark.parametrize("param, message", [
    ("sliding_friction=nan", "must be finite"),
    ("impact_spring=-1", "impact_spring must be positive"),
    ("bounciness=1", "unknown parameter 'bounciness'"),
    ("nopair:sliding_friction=0.3", "no contact pair 'nopair'"),
    ("sliding_friction", "expected name=value"),
])
def test_bad_parameters(capsys, tmp_path, param, message):
    code, _, err = run(capsys, "simulate", "bunny-drop", "--param", param, "--out", tmp_path / "t.npz")
    assert code == 1 and message in err, err
    assert not (tmp_path / "t.npz").exists()


def test_library_refuses_non_finite_parameters_and_states():
    s = load_scene("bunny-drop")
    # a target by index (what traced programs pass) out of range: an error, not JAX's silent clamp
    assert s.scene.target_index("alpha", 0) == 0 and s.scene.target_index("sliding_friction", "bunny/ground") == 0
    with pytest.raises(DanoError, match="DANO index 1 out of range: the scene has 1"):
        s.scene.set_param(s.params, "alpha", 2.0, target=1)
    with pytest.raises(DanoError, match="contact pair index -1 out of range"):
        s.scene.set_param(s.params, "sliding_friction", 0.3, target=-1)
    with pytest.raises(DanoError, match="alpha must be"):
        rollout(s.scene, s.state0, None, s.params.__class__(s.params.contact, jnp.asarray([np.inf])), 5)
    with pytest.raises(DanoError, match="initial qvel contains NaN"):
        rollout(s.scene, State(s.state0.qpos, s.state0.qvel.at[0].set(np.nan)), None, s.params, 5)
    with pytest.raises(DanoError, match=r"initial qpos must have shape \(7,\)"):
        rollout(s.scene, State(jnp.zeros(3), s.state0.qvel), None, s.params, 5)
    # the raw paths (make_data, rollout_arrays, a user's own jit of step): dano's error, not scan's IndexError
    with pytest.raises(DanoError, match=r"make_data: qpos must have shape \(7,\) for this scene, got \(6,\)"):
        rollout_arrays(s.scene, State(jnp.zeros(6), s.state0.qvel), None, s.params, 5)
    with pytest.raises(DanoError, match=r"qvel must have shape \(6,\) for this scene, got \(3,\)"):
        jax.jit(lambda v: make_data(s.scene, s.state0.qpos, v))(jnp.zeros(3))
    with pytest.raises(DanoError, match="time step dt must be positive"):
        load_scene("bunny-drop", dt=-0.01)
    # a zero quaternion: dano's error naming the body, not an all-NaN state (raw paths included)
    zero = s.state0.qpos.at[3:7].set(0.0)
    for run_it in (lambda: rollout(s.scene, State(zero, s.state0.qvel), None, s.params, 5),
                   lambda: rollout(s.scene, make_data(s.scene, s.state0.qpos).replace(qpos=zero), None, s.params, 5),
                   lambda: rollout_arrays(s.scene, State(zero, s.state0.qvel), None, s.params, 5)):
        with pytest.raises(DanoError, match=r"initial qpos: the quaternion of 'bunny' \(qpos\[3:7\] = \[0.0, "):
            run_it()
    with pytest.raises(DanoError, match="make_data: qpos: the quaternion of 'bunny'"):
        make_data(s.scene, zero)


def test_rollout_warns_of_a_deep_start():
    """The Python API warns as the command line does: the bunny's centre of mass placed 6 cm
    below where it rests (a pose's z is the centre of mass) starts hundreds of times deeper in
    the ground than its weight holds it; started in the air, nothing is said."""
    s = load_scene("bunny-drop")
    with warnings.catch_warnings():
        warnings.simplefilter("error", DanoWarning)
        rollout(s.scene, s.state0, None, s.params, 3)
    with pytest.warns(DanoWarning, match=r"bunny/ground starts \d+x deeper in contact than at rest") as caught:
        rollout(s.scene, State(s.state0.qpos.at[2].set(0.22), s.state0.qvel), None, s.params, 3)
    assert len(caught) == 1 and caught[0].filename == __file__  # (points at the caller's line)


def test_divergence_is_detected_with_the_step_number(tmp_path, capsys):
    """A spring far too soft to hold the bunny: it sinks through the ground until more than
    half of it overlaps the ground, which is reported as divergence (the implicit solve
    itself no longer blows up at large steps, see test_energy.py)."""
    s = load_scene("bunny-drop")
    soft = s.scene.default_params(impact_spring=10.0, impact_damper=0.0)
    with pytest.raises(SimulationDiverged, match=r"simulation diverged at step \d+ \(t = [\d.]+ s\).*overlap") as info:
        rollout(s.scene, s.state0, None, soft, 500)  # the command line's 5 s below: one compiled rollout
    assert 0 < info.value.step <= 300
    out = tmp_path / "t.npz"
    code, _, err = run(capsys, "simulate", "bunny-drop", "--param", "impact_spring=10", "impact_damper=0",
                       "--out", out, "--video", tmp_path / "v.mp4", "--quiet")
    assert code == 1 and "simulation diverged at step" in err
    assert list(tmp_path.iterdir()) == []


def test_initial_state_refuses_unknown_or_jointed_bodies():
    from dano.sim.scenes import initial_state, load_scene as load

    s = load("sphere-hits-bunny")
    with pytest.raises(DanoError, match="no body named 'bunyy'"):
        initial_state(s.scene, {"bunyy": ((1, 2, 3), (1, 0, 0, 0))})
    from dano.experiments.sysid_examples import pusher_scene

    scene, _ = pusher_scene()
    with pytest.raises(DanoError, match="body 'pusher' has no free joint"):
        initial_state(scene, {"pusher": ((1, 2, 3), (1, 0, 0, 0))})


@pytest.mark.parametrize("args, message", [
    (["--duration", "inf"], "--duration must be a finite positive number"),
    (["--duration", "nan"], "--duration must be a finite positive number"),
    (["--dt", "0"], "--dt must be a finite positive number"),
    (["--fps", "0", "--video", "{tmp}/v.mp4"], "--fps must be a finite positive number"),
    (["--fps", "inf", "--video", "{tmp}/v.mp4"], "--fps must be a finite positive number"),
    (["--video", "{tmp}/v.avi"], "must be .mp4 or .gif"),
    (["--duration", "1e9"], "is more than --max-steps"),
    (["--dt", "1e-7"], "is more than --max-steps"),
])
def test_simulate_options_refused_before_any_work(args, message, tmp_path, capsys):
    args = [a.replace("{tmp}", str(tmp_path)) for a in args]
    code, _, err = run(capsys, "simulate", "bunny-drop", *args, "--out", tmp_path / "t.npz", "--quiet")
    assert code == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def test_an_mp4_without_ffmpeg_is_refused_before_any_work(tmp_path, capsys, monkeypatch):
    # seen on a machine whose imageio-ffmpeg had no binary: "internal error ... please report
    # it" after the whole simulation; now one line before it, and a .gif still works
    import imageio_ffmpeg

    def missing():
        raise RuntimeError("No ffmpeg exe could be found")

    monkeypatch.setattr(imageio_ffmpeg, "get_ffmpeg_exe", missing)
    code, _, err = run(capsys, "simulate", "bunny-drop", "--video", tmp_path / "v.mp4", "--out", tmp_path / "t.npz",
                       "--quiet")
    assert code == 1 and "writing .mp4 needs ffmpeg" in err and "or write a .gif" in err
    assert list(tmp_path.iterdir()) == []
    from dano.sim.run import check_video_path

    check_video_path(tmp_path / "v.gif")


def test_a_repeated_multi_value_flag_is_a_usage_error(tmp_path, capsys):
    code, _, err = run(capsys, "simulate", "scene.xml", "--object", "builtin:bunny@0,0,1", "--object",
                       "builtin:bunny_lowpoly@1,0,1")
    assert code == 2 and "--object is given more than once" in err


def test_a_video_error_leaves_no_trajectory(tmp_path, capsys, monkeypatch):
    import dano.viz.video as video

    def broken(*args, **kwargs):
        raise DanoError("no OpenGL")

    monkeypatch.setattr(video, "render_frames", broken)
    code, _, err = run(capsys, "simulate", "bunny-drop", "--duration", "0.05", "--out", tmp_path / "t.npz",
                       "--video", tmp_path / "v.mp4", "--quiet")
    assert code == 1 and "no OpenGL" in err
    assert list(tmp_path.iterdir()) == []


def test_cli_process_routes_mujoco_warnings_and_unwinds_on_sigterm(tmp_path, monkeypatch, capsys):
    import os
    import signal

    import mujoco

    from dano._files import atomic_path
    from dano.cli import _configure_process

    monkeypatch.chdir(tmp_path)
    previous = signal.getsignal(signal.SIGTERM)
    try:
        _configure_process()
        m = mujoco.MjModel.from_xml_string("<mujoco><worldbody><body><freejoint/><geom size='.1'/></body>"
                                           "</worldbody></mujoco>")
        d = mujoco.MjData(m)
        d.qpos[0] = np.nan
        mujoco.mj_step(m, d)
        assert "warning: MuJoCo: Nan, Inf or huge value in QPOS" in " ".join(capsys.readouterr().err.split())
        with pytest.raises(SystemExit) as info:
            with atomic_path(tmp_path / "out.npz") as tmp:
                tmp.write_bytes(b"partial")
                os.kill(os.getpid(), signal.SIGTERM)
        assert info.value.code == 128 + signal.SIGTERM
        assert list(tmp_path.iterdir()) == []  # neither MUJOCO_LOG.TXT nor a temporary file
    finally:
        signal.signal(signal.SIGTERM, previous)
        mujoco.set_mju_user_warning(None)


def test_simulate_saves_its_configuration_and_reruns_it(tmp_path, capsys):
    out = tmp_path / "t.npz"
    code, _, _ = run(capsys, "simulate", "bunny-slide", "--duration", "0.2", "--param", "sliding_friction=0.4",
                     "--out", out, "--quiet")
    assert code == 0
    saved = tmp_path / "t.config.json"
    assert json.loads(saved.read_text())["param"] == ["sliding_friction=0.4"]
    code, _, _ = run(capsys, "simulate", "--config", saved, "--out", tmp_path / "again.npz", "--quiet")
    assert code == 0
    np.testing.assert_array_equal(np.load(out)["qpos"], np.load(tmp_path / "again.npz")["qpos"])
    # an option given on the command line wins, even when it equals its default
    edited = json.loads(saved.read_text())
    edited["contact_model"] = "per_sample"
    saved.write_text(json.dumps(edited))
    code, _, _ = run(capsys, "simulate", "--config", saved, "--contact-model", "centroid", "--out",
                     tmp_path / "third.npz", "--quiet")
    assert code == 0 and json.loads((tmp_path / "third.config.json").read_text())["contact_model"] == "centroid"
    bad = tmp_path / "bad.toml"
    for text, message in [('scene = "bunny-slide"\nduraton = 1.0', "unknown key 'duraton'"),
                          ('scene = "bunny-slide"\nduration = "1"', "[duration]: expected a number"),
                          ('duration = 1.0', "[scene]: missing")]:
        bad.write_text(text)
        code, _, err = run(capsys, "simulate", "--config", bad, "--out", tmp_path / "x.npz")
        assert code == 1 and f"{bad}: " in err and message in err
        assert not (tmp_path / "x.npz").exists()


def test_debug_shows_the_traceback(tmp_path, capsys):
    from dano.errors import FileFormatError

    code, _, err = run(capsys, "inspect", tmp_path / "missing.dano")
    assert code == 1 and err == f"error: {tmp_path / 'missing.dano'}: no such file"  # one line, names the file
    with pytest.raises(FileFormatError):
        main(["inspect", str(tmp_path / "missing.dano"), "--debug"])


def test_mjcf_timestep_is_honoured_unless_dt_is_given(tmp_path, capsys):
    """An MJCF with <option timestep="0.005"/> simulates at 0.005 s (saved so in the npz and its
    config), --dt overrides it; an MJCF that states none runs at 0.01 s; a bad --dt is refused
    with nothing written."""
    xml = tmp_path / "own.xml"
    xml.write_text("<mujoco><option timestep='0.005'/><worldbody><geom name='floor' type='plane' size='0 0 1'/>"
                   "</worldbody></mujoco>")
    for extra, dt in (((), 0.005), (("--dt", 0.01), 0.01)):
        out = tmp_path / f"t{dt}.npz"
        code, _, err = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.8", "--duration", 0.1,
                           "--out", out, "--quiet", *extra)
        assert code == 0, err
        z = np.load(out)
        assert np.allclose(np.diff(z["time"]), dt) and len(z["time"]) == round(0.1 / dt) + 1
        saved = json.loads((tmp_path / f"t{dt}.config.json").read_text())
        assert saved["dt"] == pytest.approx(dt)
    code, _, err = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.8", "--dt", -1,
                       "--out", tmp_path / "bad.npz")
    assert code in (1, 2) and "dt" in err and not (tmp_path / "bad.npz").exists()


def test_object_orientation_from_the_cli(tmp_path, capsys):
    """--object FILE@x,y,z,qw,qx,qy,qz places the DANO with that orientation (normalised); a zero
    quaternion or a wrong count is refused with nothing written."""
    xml = tmp_path / "floor.xml"
    xml.write_text("<mujoco><worldbody><geom name='floor' type='plane' size='0 0 1'/></worldbody></mujoco>")
    out = tmp_path / "t.npz"
    code, _, err = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.8,1,1,0,0", "--duration", 0.02,
                       "--out", out, "--quiet")
    assert code == 0, err
    assert "warning" not in err  # (starts in the air)
    q0 = np.load(out)["qpos"][0]
    np.testing.assert_allclose(q0[:3], [0, 0, 0.8], atol=1e-12)
    # placed with its centre of mass 6 cm below where it rests (a pose's z is the centre of mass, not the lowest
    # point): runs, with a warning that it starts inside the floor
    code, _, err = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.22", "--duration", 0.02,
                       "--out", out, "--quiet")
    err = " ".join(err.split())
    assert code == 0 and "warning: bunny/floor starts" in err and "deeper in contact than at rest" in err, err
    # the same start with the mass scale α 50 times smaller (the bunny's is 0.1): ψ and the resting
    # overlap m·g/k scale together, so the warning stays (572x deeper either way)
    code, _, err_light = run(capsys, "simulate", xml, "--object", "builtin:bunny@0,0,0.22", "--duration", 0.02,
                             "--param", "alpha=0.002", "--out", out, "--quiet")
    err_light = " ".join(err_light.split())
    assert code == 0 and "warning: bunny/floor starts" in err_light, err_light
    assert err_light.split(" starts ")[1].split("x")[0] == err.split(" starts ")[1].split("x")[0]
    np.testing.assert_allclose(q0[3:7], np.array([1, 1, 0, 0]) / np.sqrt(2), atol=1e-12)
    for pose, message in (("0,0,1,0,0,0,0", "must not be zero"), ("0,0", "x,y,z or x,y,z,qw,qx,qy,qz"),
                          ("0,0,1,1,nan,0,0", "finite")):
        bad = tmp_path / "bad.npz"
        code, _, err = run(capsys, "simulate", xml, "--object", f"builtin:bunny@{pose}", "--out", bad)
        assert code in (1, 2) and message in err, err
        assert not bad.exists()


def test_simulate_json_reports_the_run_and_its_compile_time(tmp_path, capsys):
    """``dano simulate --json``: one JSON object, no table; compile and run reported
    separately; the final state as the trajectory file holds it."""
    from dano.trajectory import load_trajectory

    code, text, err = run(capsys, "simulate", "bunny-drop", "--duration", "0.05", "--out", tmp_path / "t.npz", "--json")
    assert code == 0, err
    report = json.loads(text)
    assert report["scene"] == "bunny-drop" and report["steps"] == 5 and report["files"][0] == str(tmp_path / "t.npz")
    # compile and run reported apart (their values are timings: benchmarks/, not asserts)
    assert all(isinstance(report[k], float) for k in ("wall_time_s", "compile_time_s", "run_time_s"))
    traj = load_trajectory(tmp_path / "t.npz")
    np.testing.assert_allclose(report["objects"]["bunny"]["final_center_of_mass"], traj.dano_pose("bunny")[0][-1])
    assert report["final_overlap"] == {"bunny/ground": float(traj.psi[-1, 0])}
    assert report["failure_substeps"] == 1 == traj.metadata["failure_substeps"]  # nothing diverged
