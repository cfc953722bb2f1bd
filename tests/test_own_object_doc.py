"""docs/own-object.md, run as written: its ```bash and ```python blocks in order, in an empty
folder holding the user's mesh (here the low-poly bunny of ../shared), with the installed
`dano` on PATH. The journey ends in plain MuJoCo loading the identified friction; the
identified value is checked against MuJoCo's own (0.4): within 5 %, inside the interval dano reports
or with its misfit warning on; and
the exported object, pushed in plain MuJoCo, slides within 10 % of the recorded distance; the
push planned for the toy reaches its goal."""

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

DOC = Path(__file__).resolve().parents[1] / "docs" / "own-object.md"


def blocks() -> list[tuple[str, str]]:
    return re.findall(r"```(bash|python)\n(.*?)```", DOC.read_text(), flags=re.S)


@pytest.mark.slow
def test_own_object_walkthrough(tmp_path, shared):
    shutil.copy(shared / "meshes" / "bunny_lowpoly.obj", tmp_path / "toy.obj")
    # `dano` and `python` are this interpreter's (the installed package, or the source tree on PYTHONPATH)
    shim = tmp_path.parent / f"{tmp_path.name}-bin"
    shim.mkdir()
    (shim / "dano").write_text(f'#!/bin/sh\nexec "{sys.executable}" -m dano.cli "$@"\n')
    (shim / "python").write_text(f'#!/bin/sh\nexec "{sys.executable}" "$@"\n')
    for f in shim.iterdir():
        f.chmod(0o755)
    env = {**os.environ, "PATH": f"{shim}{os.pathsep}{os.environ.get('PATH', '')}", "MUJOCO_GL": "egl"}
    found = blocks()
    assert [kind for kind, _ in found].count("python") >= 2 and len(found) >= 6
    for kind, code in found:
        cmd = ["bash", "-euo", "pipefail", "-c", code] if kind == "bash" else [sys.executable, "-c", code]
        res = subprocess.run(cmd, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=900)
        assert res.returncode == 0, f"{kind} block failed:\n{code}\n--- stderr ---\n{res.stderr[-3000:]}"
    report = json.loads((tmp_path / "sysid.json").read_text())
    mu, lo, hi = report["sliding_friction"], report["sliding_friction_lower"], report["sliding_friction_upper"]
    # MuJoCo's hull contact is not dano's density contact: the estimate is close, not equal (at a friction of
    # 0.5, measured 0.506 [0.469, 0.548] with a misfit warning, the toy built upright with --up y; 0.515
    # [0.477, 0.559] since 2026-11-27's half-step start and steepness 100, which tipped the export over: the
    # upright toy tips at about 0.51, so the walkthrough now records at 0.4: 0.3954 [0.3917, 0.3992] with a
    # misfit warning, where the code before gave 0.3924 [0.3885, 0.3964]): within 5 % of MuJoCo's 0.4, and
    # where the interval misses it (the model's own error, which no interval from the residuals holds) the
    # misfit warning says so
    assert lo <= mu <= hi and abs(mu / 0.4 - 1) < 0.05, report
    assert lo <= 0.4 <= hi or any("misfits" in w for w in report["warnings"]), report
    # the export, in plain MuJoCo, given the first recording's push, stops where the recording stopped
    # (measured: 0.1355 m against 0.1340 m, +1 %; at friction 0.5 before: 0.095 m against 0.091 m)
    slides = json.loads((tmp_path / "slides.json").read_text())
    assert abs(slides["exported"] / slides["recorded"] - 1) < 0.10, slides
    # the push planned for the toy: at its goal within the constraint tolerance, the sphere sized to it
    push = json.loads((tmp_path / "push.json").read_text())
    assert push["converged"] and push["object_final_error"] < 1e-3 and push["object_goal"] == [0.0, 0.3], push
    # at rest there (push's default at_rest): slow enough that friction 0.05 stops it within about 1 mm, and
    # the scene's own rollout of the plan's controls is the plan
    assert push["object_final_speed"] < 1.5 * np.sqrt(2 * 0.05 * 9.81 * 1e-3) and push["replay_final_gap"] < 1e-6, push
    assert not push.get("warnings"), push
    assert 0 < push["pusher_max_force"] <= 2.0 * 1.001, push  # (max_force: 2 of the sphere's weights)
    x0 = np.load(tmp_path / "push-toy" / "solution.npz")["states"][0]
    assert x0[:3] == pytest.approx([0.0, -0.8 * 0.2, 0.25 * 0.2], rel=0.02)  # 0.8 L behind, at its radius L/4
    assert (tmp_path / "push-toy" / "push.mp4").stat().st_size > 1000
    assert (tmp_path / "toy.mp4").stat().st_size > 1000 and (tmp_path / "sysid-toy" / "fit.png").exists()
