"""`dano simulate` options for one's own object: initial velocities (--qvel) and the
MJCF's cameras (--camera); both refused before any run when wrong, leaving nothing."""

import json

import numpy as np

from dano.cli import main

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
