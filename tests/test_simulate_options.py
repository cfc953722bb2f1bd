"""`dano simulate` options for one's own object: initial velocities (--qvel), the MJCF's
cameras (--camera) and keyframes (--keyframe); all refused before any run when wrong, leaving
nothing."""

import json
import re

import numpy as np
import pytest

from dano.cli import main
from dano.errors import DanoError
from dano.sim.run import parse_object
from dano.sim.scenes import mjcf_setup

SCENE = """<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <camera name="side" pos="0 -2 0.5" xyaxes="1 0 0 0 0.3 1"/>
  </worldbody>
</mujoco>
"""


def test_initial_velocity_and_named_camera(tmp_path, capsys):
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE)
    out, video = tmp_path / "run.npz", tmp_path / "run.mp4"
    code = main(["simulate", str(scene), "--object", "builtin:bunny_lowpoly@0,0,0.6", "--qvel",
                 "bunny_lowpoly=1.5,0,0,0,0,4", "--duration", "0.05", "--camera", "side", "--video", str(video),
                 "-o", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    d = np.load(out)
    assert np.allclose(d["qvel"][0], [1.5, 0, 0, 0, 0, 4])
    # free flight for 0.05 s (it starts high above the floor): x moves by v t, spin stays about body z
    assert abs(d["qpos"][-1, 0] - 1.5 * 0.05) < 1e-9
    saved = json.loads((tmp_path / "run.config.json").read_text())
    assert saved["qvel"] == ["bunny_lowpoly=1.5,0,0,0,0,4"] and saved["camera"] == "side" and saved["dt"] == 0.005
    assert video.stat().st_size > 1000


def test_unknown_camera_and_bad_velocity_refused_before_running(tmp_path, capsys):
    scene = tmp_path / "scene.xml"
    scene.write_text(SCENE)
    before = set(tmp_path.iterdir())
    code = main(["simulate", str(scene), "--camera", "top", "--video", str(tmp_path / "v.mp4"), "--duration", "0.05"])
    err = capsys.readouterr().err
    assert code == 1 and "no such camera" in err and "side" in err
    for bad, message in (("bunny=1,2", "expected NAME=vx,vy,vz"), ("nobody=1,0,0", "no DANO named 'nobody'")):
        code = main(["simulate", str(scene), "--qvel", bad, "--duration", "0.05", "-o", str(tmp_path / "x.npz")])
        assert code == 1 and message in capsys.readouterr().err
    assert set(tmp_path.iterdir()) == before


KEYED = """<mujoco>
  <option timestep="0.005"/>
  <worldbody>
    <geom name="floor" type="plane" size="5 5 0.1"/>
    <body name="arm" pos="2 0 0.5">
      <joint name="turn" type="hinge" axis="0 0 1"/>
      <geom type="capsule" fromto="0 0 0 0.3 0 0" size="0.02" mass="0.5"/>
    </body>
  </worldbody>
  <actuator><position name="servo" joint="turn" kp="10"/></actuator>
  <keyframe>
    <key name="ready" qpos="0.2" qvel="0" ctrl="1.0"/>
    <key qpos="-0.4"/>
  </keyframe>
</mujoco>
"""


def test_keyframe_starts_the_mjcf_joints_and_holds_its_controls(tmp_path, capsys):
    """A key written for the MJCF alone (one hinge) sets the hinge's angle and the servo's target;
    the DANO dano appends keeps its --object pose and --qvel; the choice is saved with the run."""
    scene = tmp_path / "scene.xml"
    scene.write_text(KEYED)
    out = tmp_path / "run.npz"
    code = main(["simulate", str(scene), "--object", "builtin:bunny_lowpoly@0,0,0.6", "--qvel", "bunny_lowpoly=1,0,0",
                 "--keyframe", "ready", "--duration", "0.05", "-o", str(out), "--quiet"])
    assert code == 0, capsys.readouterr().err
    d = np.load(out)
    assert d["qpos"][0, 0] == 0.2 and np.allclose(d["qpos"][0, 1:4], [0, 0, 0.6])
    assert np.allclose(d["qvel"][0], [0, 1, 0, 0, 0, 0, 0])
    # the servo (kp 10) turns the arm towards the key's ctrl 1.0 rad; with no control it would stay at 0.2
    assert 0.25 < d["qpos"][-1, 0] < 1.0
    saved = json.loads((tmp_path / "run.config.json").read_text())
    assert saved["keyframe"] == "ready"
    # the unnamed second key by index
    code = main(["simulate", "--config", str(tmp_path / "run.config.json"), "--keyframe", "1", "-o",
                 str(tmp_path / "again.npz"), "--quiet"])
    assert code == 0, capsys.readouterr().err
    again = np.load(tmp_path / "again.npz")
    assert again["qpos"][0, 0] == -0.4 and again["qpos"][-1, 0] > -0.4  # no ctrl in that key: the servo pulls to 0


def test_unknown_or_unusable_keyframe_refused_naming_the_keys(tmp_path, capsys):
    scene = tmp_path / "scene.xml"
    scene.write_text(KEYED)
    before = set(tmp_path.iterdir())
    for key, message in (("home", "has no key 'home'; its keys (index, name): 0 'ready', 1 (unnamed)"),
                         ("2", "has no key '2'"), (" ", "give a key's name or its index")):
        code = main(["simulate", str(scene), "--keyframe", key, "--duration", "0.05", "-o", str(tmp_path / "x.npz")])
        err = capsys.readouterr().err
        assert code == 1 and message in err and err.count("\n") <= 2 and "Traceback" not in err, err
    plain = tmp_path / "plain.xml"
    plain.write_text(SCENE)
    code = main(["simulate", str(plain), "--keyframe", "0", "-o", str(tmp_path / "x.npz")])
    assert code == 1 and "has no keyframes" in capsys.readouterr().err
    code = main(["simulate", "bunny-drop", "--keyframe", "0", "-o", str(tmp_path / "x.npz")])
    assert code == 1 and "--keyframe applies to MJCF scenes" in capsys.readouterr().err
    assert set(tmp_path.iterdir()) == before | {plain}


def test_keyframe_reaching_the_danos_or_setting_mocap_is_refused(tmp_path):
    """MuJoCo fills a short key with qpos0; a key longer than the MJCF's own joints would write
    into the DANO's free joint (its pose overrides it), and mocap poses are not applied: refused."""
    bunny = [parse_object("builtin:bunny_lowpoly@0,0,0.6")]
    long_key = KEYED.replace('<key qpos="-0.4"/>', '<key name="long" qpos="-0.4 1 2 3"/>')
    mocap = KEYED.replace("</worldbody>", '<body name="target" mocap="true" pos="1 1 1"/></worldbody>').replace(
        '<key qpos="-0.4"/>', '<key name="moved" qpos="0" mpos="0 0 2"/>')
    for text, key, message in ((long_key, "long", "reaches the free joint dano adds for DANO 'bunny_lowpoly'"),
                               (mocap, "moved", "sets mpos/mquat (mocap poses)")):
        path = tmp_path / f"{key}.xml"
        path.write_text(text)
        with pytest.raises(DanoError, match=re.escape(message)):
            mjcf_setup(path, bunny, keyframe=key)
    assert mjcf_setup(tmp_path / "moved.xml", bunny, keyframe="ready").state0.qpos[0] == 0.2  # its other key is fine
