"""Trajectory optimisation with the real arm: the Menagerie Panda's own dynamics push the
bunny (beyond the paper). A file of its own so that pytest-xdist runs it beside the other
trajopt tests."""

import json

import numpy as np
import pytest

from dano.cli import main


@pytest.mark.slow
def test_push_panda_cli_optimises_the_arms_own_dynamics(tmp_path, capsys, shared, monkeypatch):
    """Beyond the paper: the Panda's joint torques (within its torque limits, joint limits as
    constraints) push the 15 cm bunny to a goal 10 cm away, 30° off the scripted push."""
    monkeypatch.setenv("MENAGERIE_ROOT", str(shared / "menagerie"))
    out = tmp_path / "panda"
    # (no video: the push-sphere test covers it; the arm's replay would compile another scan)
    code = main(["trajopt", "push-panda", "--json", "--out-dir", str(out), "--quiet", "--no-video"])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    rep = json.loads(cap.out)
    assert rep["converged"] and rep["bunny_final_error"] < 0.005 and rep["pusher_final_error"] is None, rep
    # the initial guess (a PD-tracked straight push) misses the goal by centimetres
    assert np.linalg.norm(np.array(rep["plain_push_bunny_final"][:2]) - rep["bunny_goal"]) > 0.04
    assert rep["max_control_ratio"] <= 1.0 + 1e-3 and rep["joint_limit_violation"] <= 1e-3
    sol = np.load(out / "solution.npz")
    assert sol["controls"].shape == (80, 7) and not (out / "push-panda.mp4").exists()
    assert (out / "convergence.png").stat().st_size > 10_000


def test_push_panda_without_menagerie_says_how(monkeypatch, capsys, tmp_path):
    monkeypatch.delenv("MENAGERIE_ROOT", raising=False)
    code = main(["trajopt", "push-panda", "--out-dir", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 1 and "push-panda needs" in err and "MENAGERIE_ROOT" in err and not (tmp_path / "o").exists()
