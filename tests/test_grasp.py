"""grasp-panda: the antipodal grasp search against analytic shapes, and the Panda's hand lifting
and holding the 15 cm bunny DANO in dano's simulator."""

import json

import numpy as np
import pytest

from dano.errors import DanoError
from dano.experiments.grasp import GraspPandaConfig, antipodal_grasp, build, simulate
from dano.experiments.trajopt_run import load_config


def box_surface(half, center, spacing=0.004):
    """Points (N, 3) on the faces of an axis-aligned box (a grid through each face's centre)
    and their outward normals."""
    pts, nrm = [], []
    for axis in range(3):
        a, b = [k for k in range(3) if k != axis]
        ga, gb = (np.arange(-np.floor(half[k] / spacing), np.floor(half[k] / spacing) + 1) * spacing for k in (a, b))
        A, B = np.meshgrid(ga, gb, indexing="ij")
        for sign in (-1.0, 1.0):
            p = np.zeros((A.size, 3))
            p[:, a], p[:, b], p[:, axis] = A.ravel(), B.ravel(), sign * half[axis]
            n = np.zeros_like(p)
            n[:, axis] = sign
            pts.append(p + center)
            nrm.append(n)
    return np.concatenate(pts), np.concatenate(nrm)


def test_antipodal_grasp_takes_a_box_across_its_narrow_faces_above_its_centre():
    """A 12 × 4 × 6 cm box on the table: the only pairs within the hand's 6.5 cm are across
    the 4 cm faces; the one nearest the centre of mass is chosen."""
    half, center = np.array([0.06, 0.02, 0.03]), np.array([0.5, 0.1, 0.03])
    points, normals = box_surface(half, center)
    g = antipodal_grasp(points, normals, center)
    assert abs(abs(g.axis[1]) - 1.0) < 1e-9 and abs(g.width - 0.04) < 1e-9
    assert np.linalg.norm(g.center[:2] - center[:2]) < 1e-9 and g.torque_arm < 1e-9
    assert 0.025 < g.center[2] < 0.06 and g.candidates > 10


def test_antipodal_grasp_refuses_an_object_wider_than_the_hand():
    points, normals = box_surface(np.array([0.05, 0.05, 0.03]), np.array([0.5, 0.0, 0.03]))
    with pytest.raises(DanoError, match="no antipodal grasp within the hand's opening"):
        antipodal_grasp(points, normals, np.array([0.5, 0.0, 0.03]))


def test_grasp_panda_takes_only_its_own_settings_and_reads_back_its_config(tmp_path):
    with pytest.raises(DanoError, match="grasp-panda does not use --model-error"):
        load_config("grasp-panda", model_error=0.3)
    cfg = load_config("grasp-panda", contact_model="per_sample")
    path = tmp_path / "config.json"
    import dataclasses

    path.write_text(json.dumps(dataclasses.asdict(cfg)))
    assert load_config(str(path)) == cfg
    path.write_text(json.dumps({**dataclasses.asdict(cfg), "grip_forces": [30.0, 90.0]}))
    with pytest.raises(DanoError, match="grip_forces out of range"):
        load_config(str(path))
    path.write_text(json.dumps({**dataclasses.asdict(cfg), "approach_iterations": 0}))
    with pytest.raises(DanoError, match="approach_iterations out of range"):
        load_config(str(path))


@pytest.mark.slow
def test_grasp_panda_cli_lifts_and_holds_the_bunny(shared, monkeypatch, tmp_path, capsys):
    """`dano trajopt CONFIG --json` for grasp-panda with a two-force scan: the constrained
    iLQR's approach reaches the pre-grasp pose at rest (its constraints met, at a tenth of the
    scripted approach's cost) and the executed motion follows it there; the hand grasps the
    15 cm bunny at the chosen antipodal pair, lifts it ≥ 9 cm (goal 10 cm) and holds it for
    1 s with under 5 mm of slip at 40 N per finger; at 10 N it slips more and the scan does
    not choose it (centroid model); the outputs are written."""
    from dano.cli import main

    monkeypatch.setenv("MENAGERIE_ROOT", str(shared / "menagerie"))
    config = tmp_path / "grasp.json"
    config.write_text(json.dumps({"task": "grasp-panda", "grip_forces": [10.0, 40.0], "compare_models": False}))
    out = tmp_path / "out"
    code = main(["trajopt", str(config), "--json", "--quiet", "--no-video", "--out-dir", str(out)])
    cap = capsys.readouterr()
    assert code == 0, cap.err
    rep = json.loads(cap.out)
    weak, firm = rep["scan"]
    assert rep["converged"] and rep["grip_force"] == 40.0 and firm["success"] and not weak["success"], rep
    assert rep["lift_height"] > 0.09 and rep["slip_mm"] < 5.0 and not firm["diverged"], rep
    assert not weak["diverged"] and weak["slip_mm"] > firm["slip_mm"], rep
    assert rep["grasp"]["width"] < 0.065 and rep["grasp"]["torque_arm"] < 0.06
    assert list(rep["contact_models"]) == ["centroid"]
    a = rep["approach"]
    assert a["optimised"] and a["converged"] and a["max_violation"] < 1e-3, a
    assert a["final_error_rad"] < 1e-3 and a["final_speed_rad_s"] < 1e-3 and a["min_clearance_m"] > -1e-3, a
    assert a["cost"] < 0.2 * a["scripted_cost"], a
    # executed at 2 ms with the bunny and table present, the PD-tracked plan ends within 0.01
    # rad of the pre-grasp; the scripted approach (its PD simulated in the planning scene)
    # ends more than 0.1 rad behind it
    assert a["executed_final_error_rad"] < 0.01 < 0.1 < a["scripted_final_error_rad"], a
    sol = np.load(out / "solution.npz")
    assert sol["states"].shape[0] == sol["controls"].shape[0] + 1 and sol["controls"].shape[1] == 8
    assert sol["approach_states"].shape == (101, 18) and sol["approach_controls"].shape == (100, 7)
    assert json.loads((out / "config.json").read_text())["grip_forces"] == [10.0, 40.0]
    assert not (out / "grasp-panda.mp4").exists()


@pytest.mark.slow
def test_stiff_finger_contact_stays_bounded_at_10_ms(shared, monkeypatch):
    """Stiff pads (impact spring 1e6) on light, joint-limited fingers at h = 10 ms: with one
    constraint pass (MuJoCo's solver sees only the contact force at the step's start velocity)
    the fingers are driven through their limits, in a run whose state blows up (|qvel| > 1e3:
    ``diverged``) or by more than 1 cm out of their range (on a VM without AVX-512 on
    2026-11-27 no run diverged, but the fingers reached −0.33 m and 0.21 m and the 50 N run
    dropped the object); the step's default second pass keeps every run bounded, the fingers
    within 1 cm of their 0–4 cm range and the object held. The firm grip (50 N) lifts it
    within 2 cm of the 0.1 m target with under 5 mm of slip; the 20 N grip is marginal at
    10 ms, its slip set by rounding: it lifted above 8 cm on the VMs of earlier sessions and
    7.55 cm with 10.4 mm of slip on an AVX-512 EPYC VM on 2026-11-26, the same code
    (7ccca4e), so for it the test asks only that it holds."""
    from dano.sim import NewtonOptions

    monkeypatch.setenv("MENAGERIE_ROOT", str(shared / "menagerie"))
    task = build(GraspPandaConfig(dt=0.01, compare_models=False))
    one, _ = simulate(task, [20.0, 50.0], NewtonOptions(constraint_passes=1))
    two, _ = simulate(task, [20.0, 50.0])

    def fingers_in_range(run):
        fingers = run.states[:, 7:9]
        return bool(fingers.min() > -0.01 and fingers.max() < 0.05)

    assert any(r.diverged or not fingers_in_range(r) for r in one)
    for r in two:
        assert not r.diverged and r.lift_height > 0.05, r  # held, not dropped
        assert fingers_in_range(r)
    assert two[1].lift_height > 0.08 and two[1].slip_mm < 5.0, two[1]
