"""Identification you can trust with its defaults (issue 28): a user's object from another engine
(plain MuJoCo C), calibrated intervals, the noise from the observations, the size-weighted
rotations, a neutral sliding drag, and one compilation per problem structure."""

import dataclasses
import io
import json
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from rich.console import Console

from dano._tables import sysid_table
from dano.asset import build
from dano.cli import main
from dano.errors import DanoError
from dano.fields import BoxField
from dano.sim import DanoObject, compose
from dano.sysid import FitParameter, SysIdProblem, Weights, identify, observation_noise
from dano.experiments.sysid_examples import analytic_slides, interval_coverage
from dano.sysid.problem import _residuals_and_jacobian_jit, rotation_length, start_velocity_disagreement
from dano.sysid.solve import _first_frames_if_they_fit, _scan


@pytest.fixture(scope="module")
def box():
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    return compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.0025)


@pytest.mark.slow
def test_own_object_from_plain_mujoco_with_the_first_toml(shared, tmp_path, capsys):
    """The low-poly bunny scaled to 0.2 m and 0.7 kg, three slides in plain MuJoCo C at friction
    0.5 (elliptic cone) recorded at 100 Hz as CSV; the TOML a new user writes first (no
    [contact], no [options]). The default answer lies within 5 % of 0.5, or its interval covers
    0.5 and a warning says the model misfits; the sliding drag is held neutral and said so."""
    from dano.experiments.mujoco_c import mujoco_c_slides

    made = mujoco_c_slides(tmp_path / "toy", mesh=shared / "meshes" / "bunny_lowpoly.obj")
    assert "[contact]" not in made["toml"].read_text() and "[options]" not in made["toml"].read_text()
    assert main(["sysid", str(made["toml"]), "--json", "--out-dir", str(tmp_path / "out")]) == 0
    report = json.loads(capsys.readouterr().out)
    mu, lower, upper = report["sliding_friction"], report["sliding_friction_lower"], report["sliding_friction_upper"]
    misfit = any("misfits" in w for w in report["warnings"])
    assert abs(mu / 0.5 - 1) < 0.05 or (lower <= 0.5 <= upper and misfit), report
    assert lower < mu < upper
    assert any("sliding_drag is held at 0.0 (a Coulomb world)" in n for n in report["notes"])
    assert report["noise_estimate"]["expected_rms_residual"] < 1e-4  # MuJoCo's poses carry no noise
    assert misfit  # two engines' contact models: the residual is far above that
    # single steps: no step fails at the answer, nor does a rollout diverge at the scan's starts (measured
    # 2026-11-29: one diverges at the scan's far end, friction 2, said in a warning: no reason for substeps)
    assert report["failure_substeps"] == 1 and not any("substeps" in n for n in report["notes"])


def _mujoco_c_mug_tosses(folder: Path) -> list[Path]:
    """A review's mug (2026-12-02) as a new user makes it: trimesh and manifold3d in millimetres
    (80 mm across, 90 mm tall, a bore to an 8 mm floor, a torus handle), built at 0.3 kg, exported
    to MJCF and tossed three times in plain MuJoCo C (2 ms steps, elliptic cone, friction 0.5)
    from 12–18 cm, tilted and spinning, 100 frames at 100 Hz each, written to ``folder`` as
    ``mug.dano`` and ``toss_1.csv`` … ``toss_3.csv`` (t, x, y, z, qw, qx, qy, qz; seconds,
    metres). Returns the CSVs' paths."""
    import mujoco
    import trimesh

    body = trimesh.creation.cylinder(radius=40, height=90, sections=96)
    body.apply_translation([0, 0, 45])
    bore = trimesh.creation.cylinder(radius=32, height=90, sections=96)
    bore.apply_translation([0, 0, 53])
    handle = trimesh.creation.torus(major_radius=22, minor_radius=5, major_sections=64, minor_sections=24)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    handle.apply_translation([40, 0, 45])
    mug = trimesh.boolean.difference([trimesh.boolean.union([body, handle], engine="manifold"), bore],
                                     engine="manifold")
    mug.export(folder / "mug.obj")
    assert main(["build", str(folder / "mug.obj"), "-o", str(folder / "mug.dano"), "--scale", "0.001",
                 "--mass", "0.3"]) == 0
    assert main(["export", str(folder / "mug.dano"), "-o", str(folder / "mug.xml")]) == 0
    spec = mujoco.MjSpec.from_file(str(folder / "mug.xml"))
    spec.option.timestep, spec.option.cone = 0.002, mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1])
    for geom in spec.geoms:
        geom.friction = [0.5, 0.005, 0.0001]
    model = spec.compile()
    data = mujoco.MjData(model)
    files = []
    for k, (h, axis, angle, v, w) in enumerate([(0.15, [1, 0, 0], 0.6, [0.8, 0.2, 0.5], [3.0, -1.0, 4.0]),
                                                 (0.18, [0, 1, 1], 1.0, [-0.6, 0.7, 0.3], [-2.0, 4.0, 2.0]),
                                                 (0.12, [1, 1, 0], 0.4, [0.5, -0.9, 0.0], [1.0, 2.0, -5.0])]):
        mujoco.mj_resetData(model, data)
        axis = np.asarray(axis, float) / np.linalg.norm(axis)
        data.qpos[:7] = [0, 0, h, np.cos(angle / 2), *(np.sin(angle / 2) * axis)]
        data.qvel[:6] = [*v, *w]
        files.append(_record_csv(model, data, folder / f"toss_{k + 1}.csv", frames=100))
    return files


def _record_csv(model, data, path: Path, frames: int, steps_per_frame: int = 5) -> Path:
    """Step plain MuJoCo C from ``data`` and write the free body's pose every ``steps_per_frame``
    steps, ``frames`` rows, as a trajectory CSV at ``path`` (t from the first row [s], x y z [m],
    qw qx qy qz); returns ``path``."""
    import mujoco

    rows, t0 = [], data.time
    for _ in range(frames):
        rows.append([data.time - t0, *data.qpos[:7]])
        for _ in range(steps_per_frame):
            mujoco.mj_step(model, data)
    np.savetxt(path, rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")
    return path


@pytest.mark.slow
def test_a_mug_tossed_in_plain_mujoco_rolls_and_its_friction_is_one_sided(tmp_path, capsys):
    """Tossed, the mug lands and rolls, which depends on the friction little: its whole tosses'
    cost stays within the interval's threshold from about 0.25 to the range's top. The default
    identification says so (status one-sided, no standard error: the review read 0.293 ± 0.0012
    beside [0.2507, 2] before) and its interval holds MuJoCo's 0.5."""
    files = _mujoco_c_mug_tosses(tmp_path)
    capsys.readouterr()
    # the tosses' TOML from the template, edited as it says (the files, dt 2.5 ms, 4 substeps)
    assert main(["sysid", "--template", str(tmp_path / "mug.dano")]) == 0
    text = capsys.readouterr().out
    block = text[text.index("[[trajectory]]"):text.index("[[parameter]]")]
    assert "auto_windows" in text  # the template names the windows for tosses
    toml = text.replace(block, "".join(block.replace("mug_1.csv", str(f)) for f in files))
    toml = toml.replace("dt = 0.01 ", "dt = 0.0025 ").replace("# substeps = 1 ", "substeps = 4 ")
    (tmp_path / "tosses.toml").write_text(toml)
    assert main(["sysid", str(tmp_path / "tosses.toml"), "--json", "--out-dir", str(tmp_path / "out")]) == 0
    report = json.loads(capsys.readouterr().out)
    lower, upper = report["sliding_friction_lower"], report["sliding_friction_upper"]
    assert lower <= 0.5 <= upper and upper == 2.0, report
    assert report["identifiability"]["sliding_friction"]["status"] == "one-sided"
    assert report["sliding_friction_std"] is None
    assert any("bounded on one side only" in w and f"sliding_friction >= {lower:.4g}" in w and "slides on a face" in w
               for w in report["warnings"]), report["warnings"]


@pytest.mark.slow
def test_a_box_from_plain_mujoco_at_one_step_per_frame(tmp_path, capsys):
    """A new user's box (12 × 8 × 5 cm, 0.4 kg; trimesh's box), three slides in plain MuJoCo C
    at friction 0.35 recorded at 50 Hz for 0.6 s, the first TOML (dt = the frame interval, one
    step per frame). Hard Coulomb friction and a 20 ms step: the defaults once said 0.3426
    without noise and 0.369 [0.366, 0.372] with 1 mm of it, no warning (the paper code's
    friction steepness and the start velocity half a step off). Now within 1 % of 0.35 without
    noise (0.3524) and within 2 % with 1 mm (0.3559 [0.3531, 0.3586]: the interval still
    misses by 0.1 %, as in 3 of 5 draws, docs/sysid.md)."""
    import trimesh

    from dano.experiments.mujoco_c import mujoco_c_slides

    trimesh.creation.box(extents=(0.12, 0.08, 0.05)).export(tmp_path / "box.obj")
    made = mujoco_c_slides(tmp_path / "box", mesh=tmp_path / "box.obj", size=0.12, mass=0.4, friction=0.35,
                           rate=50.0, duration=0.6)
    rng = np.random.default_rng(100)
    noisy = tmp_path / "noisy"
    noisy.mkdir()
    for csv in made["csv"]:
        rows = np.loadtxt(csv, delimiter=",", skiprows=1)
        rows[:, 1:4] += 0.001 * rng.standard_normal(rows[:, 1:4].shape)
        np.savetxt(noisy / csv.name, rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="", fmt="%.9g")
    toml = made["toml"].read_text().replace('asset = "toy.dano"', f'asset = "{made["dano"]}"')
    (noisy / "problem.toml").write_text(toml)
    for problem, tolerance in ((made["toml"], 0.01), (noisy / "problem.toml", 0.02)):
        assert main(["sysid", str(problem), "--json", "--out-dir", str(problem.parent / "out")]) == 0
        report = json.loads(capsys.readouterr().out)
        mu, lower, upper = report["sliding_friction"], report["sliding_friction_lower"], report["sliding_friction_upper"]
        assert abs(mu / 0.35 - 1) < tolerance and lower <= mu <= upper, (problem, mu, lower, upper)


@pytest.mark.slow
def test_default_intervals_are_calibrated_over_50_seeds():
    """dano's own slides with 2 mm noise in every frame, 4 trajectories, 50 seeds: the default 95 %
    interval covers the true friction in 90-99 % of them (docs/sysid.md has the table)."""
    r = interval_coverage(seeds=50)
    assert 45 <= r["covers"] <= 49, {k: v for k, v in r.items() if k != "per_seed"}
    assert r["seeds_with_warnings"] <= 5  # the model is right: misfit warnings would be false alarms


def test_noise_is_estimated_from_the_observations(box):
    """Third differences recover the noise of slides with 1 mm noise (x, y) within 15 %, see no
    noise in z, and the rms residual that noise alone leaves is what a good fit reaches."""
    obs = analytic_slides(0, 0.05, 8, frames=40, noise=0.001)
    problem = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                           weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4)
    noise = observation_noise(problem)
    assert noise["position_m"][0] == pytest.approx(1e-3, rel=0.15)
    assert noise["position_m"][1] == pytest.approx(1e-3, rel=0.15)
    assert noise["position_m"][2] == 0.0 and noise["rotation_deg"] == 0.0
    short = SysIdProblem(box, analytic_slides(0, 0.05, 1, frames=5, noise=0.001),
                         [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], substeps=4)
    assert observation_noise(short)["position_m"] is None  # too short to tell: None, never NaN


def test_rotations_are_weighed_by_size_and_drag_is_neutral(box):
    """By default a rotation counts as the displacement of the mass points it causes,
    √(tr J / 3m) per radian (for a solid box of sides a, b, c: √((a² + b² + c²)/18)); with
    friction identified the sliding drag is held at 0, said in the notes; given base parameters
    are used as they are, a drag in them said in the notes too."""
    asset = box.assets[0]
    J = np.asarray(asset.inertia)
    assert rotation_length(asset) == pytest.approx(np.sqrt(np.trace(J) / (3 * asset.mass)))
    a, b, c = 0.2, 0.2, 0.1  # BoxField takes half extents
    assert rotation_length(asset) == pytest.approx(np.sqrt((a * a + b * b + c * c) / 18), rel=0.03)
    obs = analytic_slides(0, 0.05, 2, noise=0.0)
    problem = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], substeps=4)
    assert np.asarray(problem.base_params.contact.sliding_drag).tolist() == [0.0]
    assert any("sliding_drag is held at 0.0 (a Coulomb world)" in n for n in problem.notes)
    np.testing.assert_allclose(problem.rotation_weights(), [rotation_length(asset)])
    given = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], substeps=4,
                         base_params=box.default_params())
    assert np.asarray(given.base_params.contact.sliding_drag).tolist() == [0.1]
    # the README's pattern copied onto data from elsewhere: the given drag is said, once
    assert len(given.notes) == 1 and "sliding_drag is held at 0.1 (given" in given.notes[0]
    assert dataclasses.replace(given, substeps=4).notes == given.notes
    neutral = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], substeps=4,
                           base_params=box.default_params(sliding_drag=0.0))
    assert not neutral.notes
    # derived anew, not carried over: the drag replaced by 0, the note goes; the Coulomb note stays
    assert not dataclasses.replace(given, base_params=box.default_params(sliding_drag=0.0)).notes
    assert dataclasses.replace(problem, substeps=4).notes == problem.notes


def test_a_lone_objects_mass_scale_is_flat_not_at_a_bound(box):
    """A DANO that touches only the floor moves the same at any mass scale (its contact forces
    and its mass both scale with α): fitted, α is reported flat with the reason and no advice
    to widen a bound (on Spot from MuJoCo C the estimate stopped at its lower bound, 0.2 of
    the asset's α, and was reported "at bound"). A cost that keeps falling beyond a narrow box
    stays "at bound", with that advice, though the box is flat at the noise's scale."""
    obs = analytic_slides(0, 0.05, 2, noise=0.0, frames=12)
    alpha = float(box.assets[0].alpha)
    fit = [FitParameter("sliding_friction", 0.3, 0.0, 2.0), FitParameter("alpha", 0.8 * alpha, 0.2 * alpha, 3 * alpha)]
    r = identify(SysIdProblem(box, obs, fit, substeps=4), profile_points=8)
    assert r.identifiability["alpha"]["status"] == "flat"
    assert any("alpha is not identifiable" in w and "known mass" in w for w in r.warnings)
    assert not any("sits at its" in w and w.startswith("alpha") for w in r.warnings)
    # a cost that keeps falling beyond a narrow box is "at bound", with the advice to widen it
    narrow = [FitParameter("sliding_friction", 0.3, 0.3, 0.303)]
    r = identify(SysIdProblem(box, obs, narrow, substeps=4), profile_points=8)
    assert r.identifiability["sliding_friction"]["status"] == "at bound"
    assert any("sits at its upper bound" in w for w in r.warnings)


def test_an_interval_that_runs_to_one_end_far_beyond_the_curvature_is_one_sided():
    """An interval is one-sided where it reaches one end of its profile's range and not the
    other and is more than twice as wide as the local curvature's standard error gives: the
    review's mug tossed in plain MuJoCo C, whose friction's cost stayed within the threshold
    from 0.2507 to the range's top, 2, beside a standard error of 0.00122 (inflation 199)."""
    from types import SimpleNamespace

    from dano.sysid.solve import _one_sided

    pr = SimpleNamespace(values=np.linspace(0.0, 2.0, 33))
    mug = 2 * 1.96 * 0.00122 * np.sqrt(199.0)  # 0.0675: the interval its standard error gives
    assert _one_sided(pr, 0.2507, 2.0, mug, 0.87) == ">="  # bounded from below only
    assert _one_sided(pr, 0.0, 1.2, 0.1, 0.6) == "<="  # bounded from above only
    assert _one_sided(pr, 0.2507, 0.33, mug, 0.04) is None  # both ends inside the range: two-sided
    assert _one_sided(pr, 0.0, 2.0, mug, 1.0) is None  # both ends: flat, not one-sided
    assert _one_sided(pr, 0.0, 0.03, 0.05, 0.015) is None  # a small friction against its bound at 0: identified
    # no finite standard error: one-sided where the interval covers half of the scanned box or more
    assert _one_sided(pr, 0.9, 2.0, np.nan, 0.55) == ">=" and _one_sided(pr, 1.6, 2.0, np.nan, 0.2) is None


def test_the_local_minima_warning_leaves_out_a_flat_parameter(box):
    """Starts that end near the best cost at other estimates are warned of as local minima,
    naming only the parameters that differ; once a parameter is found flat (its own warning
    says it is not identifiable) it leaves that warning, which goes where nothing else differs."""
    from types import SimpleNamespace

    from dano.sysid.solve import _disagreement, _drop_from_minima

    obs = analytic_slides(0, 0.05, 2, noise=0.0, frames=12)
    fit = [FitParameter("sliding_friction", 0.3, 0.0, 2.0), FitParameter("alpha", 1.0, 0.2, 3.0)]
    problem = SysIdProblem(box, obs, fit, substeps=4)

    def result(mu, alpha, cost):
        return SimpleNamespace(estimates=np.array([mu, alpha]), final_cost=cost, standard_errors=np.array([0.01, np.nan]),
                               warnings=[], scan={})

    best = result(0.45, 1.0, 1.0)
    others = [result(0.45, 2.5, 1.01), result(0.60, 0.4, 1.02), result(0.90, 2.0, 2.0)]  # (the last: 2x the cost)
    best.warnings = _disagreement(problem, best, [best] + others, scan_best=1.0)
    assert len(best.warnings) == 1 and best.warnings[0].startswith("2 other start(s)")
    assert "sliding_friction 0.45..0.6, alpha 0.4..2.5" in best.warnings[0]
    _drop_from_minima(problem, best, "alpha")  # the friction's own minimum stays, alone
    assert len(best.warnings) == 1 and best.warnings[0].startswith("1 other start(s)")
    assert "(sliding_friction 0.45..0.6)" in best.warnings[0]
    only_alpha = result(0.45, 1.0, 1.0)
    only_alpha.warnings = _disagreement(problem, only_alpha, [only_alpha, others[0]], scan_best=1.0) + ["kept"]
    assert "(alpha 1..2.5)" in only_alpha.warnings[0]
    only_alpha.estimates = np.array([0.451, 1.1])  # (the verification's restarts may move the best since)
    _drop_from_minima(problem, only_alpha, "alpha")
    assert only_alpha.warnings == ["kept"] and only_alpha.scan["local_minima"] == []


def test_noisy_starts_have_their_velocities_fitted_by_default(box):
    """2 mm of noise at 100 Hz makes a start velocity taken by finite differences uncertain by
    ~0.5 m/s (a quarter of these slides' speeds): by default (fit_velocity="auto") the starts'
    velocities are fitted, said in the notes; with fit_velocity="" a warning names the option;
    given (qvel0), they are neither fitted nor warned of."""
    noisy = analytic_slides(0, 0.05, 4, noise=0.002)
    from_frames = [dataclasses.replace(o, qvel0=None) for o in noisy]
    fit = [FitParameter("sliding_friction", 0.3, 0.0, 2.0)]
    weights = Weights((1.0, 1.0, 0.0), 0.0)

    def run(obs, **options):
        problem = SysIdProblem(box, obs, fit, weights=weights, substeps=4, **options)
        r = identify(problem, scan=0, profile_points=0)
        said = [w for w in r.warnings if "finite differences of the observed frames" in w]
        assert not any("evaluation limit" in w for w in r.warnings)  # (10 per parameter, nuisance included)
        auto = [n for n in r.notes if n.startswith("start velocities (fit_velocity auto)")]
        run.last = (problem, r)
        return problem.fit_velocity, said, auto, r.estimates[0]

    axes, said, (note,), estimate = run(from_frames)  # (x and y weighed: those two)
    assert axes == "xy" and said == [] and "% of the typical moving start's speed" in note
    # the CLI's table: the 8 start offsets in one row (all of them are in result.json)
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(sysid_table("p.toml", *run.last, {}, Path("out")))
    text = console.export_text()
    assert "v0[...]: 8 start velocity offsets [m/s]" in text and "v0[0]" not in text
    axes, (warning,), auto, unfitted = run(from_frames, fit_velocity="")
    assert axes == "" and auto == [] and 'fit_velocity = "xy" or "auto"' in warning
    assert abs(estimate - 0.45) < abs(unfitted - 0.45)  # the truth: closer with the starts fitted
    assert run(noisy)[:3] == ("", [], [])
    # no noise (rounding only), or still objects: nothing to fit
    exact = analytic_slides(0, 0.05, 4, noise=0.0)
    assert SysIdProblem(box, [dataclasses.replace(o, qvel0=None) for o in exact], fit, weights=weights,
                        substeps=4).fit_velocity == ""
    still = [dataclasses.replace(o, qvel0=None, poses={"box": np.repeat(o.poses["box"][:1], len(o.time), 0)
                                                      + np.c_[np.random.default_rng(1).normal(0, 1e-3, (len(o.time), 2)),
                                                              np.zeros((len(o.time), 5))]}) for o in exact]
    assert SysIdProblem(box, still, fit, weights=weights, substeps=4).fit_velocity == ""
    # windows whose nuisance velocities would outnumber the residuals: not fitted, said why
    windowed = SysIdProblem(box, from_frames, fit, weights=Weights((1.0, 0.0, 0.0), 0.0), substeps=4, window=2,
                            fit_position="x", fit_angular_velocity="z")
    assert windowed.fit_velocity == "" and any("would outnumber the residuals" in n for n in windowed.notes)


def _first_frame_off(obs, name, offset):
    """The observation with its first frame moved back along its motion by ``offset`` [m] (a
    pose read a substep apart from the rest, a tracker's cold start)."""
    p = np.array(obs.poses[name], dtype=np.float64)
    u = p[1, :3] - p[0, :3]
    p[0, :3] -= offset * u / np.linalg.norm(u)
    return dataclasses.replace(obs, poses={**obs.poses, name: p})


def test_a_first_frame_off_has_the_start_velocities_fitted(box):
    """Exact closed-form Coulomb slides (no noise) whose first frame lies 2 mm back along the
    motion: the start velocities that finite differences take from the first three frames
    disagree with the next four frames' motion, which the noise cannot explain. By default
    each start is taken from the parabola through the next four frames (position and
    velocity), its velocity is fitted, and the note says why: within 1 % of the truth (0.45).
    Started from the first frames and not fitted (both turned off) it is 90 % high, and a
    warning names the option. The same slides with every frame right: nothing changes."""
    exact = [dataclasses.replace(o, qvel0=None) for o in analytic_slides(0, 0.05, 4, noise=0.0)]
    off = [_first_frame_off(o, "box", 0.002) for o in exact]
    fit = [FitParameter("sliding_friction", 0.3, 0.0, 2.0)]
    weights = Weights((1.0, 1.0, 0.0), 0.0)
    pose = lambda obs, **kw: SysIdProblem(box, obs, fit, weights=weights, substeps=4, **kw)  # noqa: E731
    gap, noise, typical = start_velocity_disagreement(off, pose(off).segments, [0.0, 0.0, 0.0], "xy")
    assert gap > 0.1 * typical and noise == 0.0
    # windows inside a run start from ordinary frames (often just before an impact): not counted
    windowed = pose(off, window=5, fit_velocity="")
    assert len(windowed.segments) > 4
    assert start_velocity_disagreement(off, windowed.segments, [0.0, 0.0, 0.0], "xy") == (gap, noise, typical)
    right = pose(exact)
    assert start_velocity_disagreement(exact, right.segments, [0.0, 0.0, 0.0], "xy")[0] < 1e-6 * typical
    assert (right.fit_velocity, right.start_velocity) == ("", "first frames")  # a parabola: they agree
    problem = pose(off)
    (note,) = [n for n in problem.notes if n.startswith("start velocities (fit_velocity auto)")]
    assert (problem.fit_velocity, problem.start_velocity) == ("xy", "next frames")
    assert "a first frame may be off" in note and 'start_velocity = "next frames"' in note
    # what identify compares with the scan on (there: the slow T-block test below)
    plain = problem.started_from_first_frames()
    assert (plain.start_velocity, plain.fit_velocity) == ("first frames", "")
    assert not any(n.startswith("start velocities") for n in plain.notes)
    assert right.started_from_first_frames() is right
    only_start = pose(off, fit_velocity="")
    (note,) = [n for n in only_start.notes if n.startswith("start velocities (start_velocity auto)")]
    assert only_start.start_velocity == "next frames" and "a first frame may be off" in note
    assert only_start.started_from_first_frames().start_velocity == "first frames"
    fitted = identify(problem, scan=0, profile_points=0)
    unfitted = identify(pose(off, fit_velocity="", start_velocity="first frames"), scan=0, profile_points=0)
    assert any('fit_velocity = "xy" or "auto"' in w and "a first frame may be off" in w for w in unfitted.warnings)
    assert not any("a first frame may be off" in w for w in fitted.warnings)
    # (measured: 0.4503, and 0.856 from the first frames; the first frame stays in the residuals, an outlier)
    assert abs(fitted.estimates[0] / 0.45 - 1) < 0.01 and abs(unfitted.estimates[0] / 0.45 - 1) > 0.5
    with pytest.raises(DanoError, match="start_velocity must be one of"):
        pose(exact, start_velocity="first")


def test_identify_refuses_bad_options_before_it_evaluates_anything(box):
    """Options out of range end in one clear error before any scan runs (also where the
    first-frames comparison would scan first: a first frame that is off)."""
    off = [_first_frame_off(dataclasses.replace(o, qvel0=None), "box", 0.002) for o in analytic_slides(0, 0.05, 2, noise=0.0)]
    problem = SysIdProblem(box, off, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                           weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4)
    assert problem.start_velocity == "next frames"
    for options, match in (({"scan": 1}, "scan must be 2 to 64"), ({"scan": 65}, "scan must be 2 to 64"),
                           ({"starts": 0}, "starts 1 to 16"), ({"jacobian": "cd"}, "jacobian must be"),
                           ({"horizons": (1.5,)}, "horizons must be fractions")):
        with pytest.raises(DanoError, match=match):
            identify(problem, **options)
    with pytest.raises(DanoError, match="needs a float64 scene"):
        identify(dataclasses.replace(problem, scene=box.astype(jnp.float32)))


def test_next_frames_start_leaves_the_first_frame_out():
    """A constant acceleration (a flight, a slide) with its first frame 2 mm off: the start
    from the next four frames' parabola is its exact position at the first frame's time and
    its exact velocity half a step before (rounding only); too few frames are refused."""
    from dano.sysid.problem import next_frames_start

    t = np.arange(6) * 0.01
    x0, v, a = np.array([0.1, 0.2, 0.05]), np.array([1.0, 0.4, -0.2]), np.array([0.3, -1.2, -9.81])
    poses = np.c_[x0 + np.outer(t, v) + 0.5 * np.outer(t**2, a), np.tile([1.0, 0, 0, 0], (6, 1))]
    poses[0, :3] += 0.002
    position, velocity = next_frames_start(t, poses, 0.0025)
    np.testing.assert_allclose(position, x0, atol=1e-12)
    np.testing.assert_allclose(velocity, np.r_[v - a * 0.00125, 0, 0, 0], atol=1e-12)
    with pytest.raises(DanoError, match="needs 5 frames"):
        next_frames_start(t[:4], poses[:4])


def test_plain_mujoco_slides_read_a_substep_apart_have_their_starts_fitted(shared, tmp_path):
    """Plain MuJoCo C slides of the low-poly bunny (0.2 m, 0.7 kg), as a new user recorded them
    reading the poses MuJoCo derives after mj_step (xipos), which lag qpos by one substep: every
    frame but the first 2 ms late (moved back by the recorded velocity × 2 ms). Their TOML with
    defaults starts each slide from the frames after its first and fits the start velocities;
    the slides as recorded from qpos neither (their noise-free first frames agree with the
    motion that follows within 3.5 %, the median of the three)."""
    from dano.experiments.mujoco_c import mujoco_c_slides
    from dano.sysid.config import problem_from_toml

    made = mujoco_c_slides(tmp_path / "toy", mesh=shared / "meshes" / "bunny_lowpoly.obj", num_samples=500)
    recorded = problem_from_toml(made["toml"])[0]
    assert (recorded.fit_velocity, recorded.start_velocity) == ("", "first frames")
    # four slides (another seed) as recorded: their first frames disagree with the next four by 6 %
    # of the speed, their second frames by more (the contact settling after the launch): not a first
    # frame that is off (flagged before the second frame's comparison, measured: 0.477 [0.447, 0.509]
    # against 0.491 [0.477, 0.505] for 0.5)
    four = mujoco_c_slides(tmp_path / "four", mesh=shared / "meshes" / "bunny_lowpoly.obj", num_samples=500,
                           slides=4, seed=2)
    four_problem = problem_from_toml(four["toml"])[0]
    gap, _, typical = start_velocity_disagreement(four_problem.observations, four_problem.segments, None, "xyz")
    later = start_velocity_disagreement(four_problem.observations, four_problem.segments, None, "xyz", shift=1)
    assert 0.05 < gap / typical < 0.15 and later[0] > gap, (gap, typical, later)
    assert (four_problem.fit_velocity, four_problem.start_velocity) == ("", "first frames")
    _lag_every_frame_but_the_first(four["csv"])
    assert problem_from_toml(four["toml"])[0].start_velocity == "next frames"
    _lag_every_frame_but_the_first(made["csv"])
    problem = problem_from_toml(made["toml"])[0]
    assert (problem.fit_velocity, problem.start_velocity) == ("xyz", "next frames")
    assert any("a first frame may be off" in n for n in problem.notes)


def _lag_every_frame_but_the_first(csvs, lag=0.002):
    """Rewrites the CSVs as read from MuJoCo's xipos after mj_step: every frame but the first
    ``lag`` [s] late (moved back by the recorded velocity × lag; the error, ½·a·lag², is 10 µm)."""
    for csv in csvs:
        rows = np.loadtxt(csv, delimiter=",", skiprows=1)
        rows[1:, 1:4] -= lag * np.gradient(rows[:, 1:4], rows[:, 0], axis=0)[1:]
        np.savetxt(csv, rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="", fmt="%.9g")


@pytest.mark.slow
def test_own_object_read_a_substep_apart_with_the_first_toml(shared, tmp_path, capsys):
    """The first TOML's bunny slides (plain MuJoCo C, friction 0.5) read a substep apart: the
    defaults once said 0.192 [0.174, 0.214] (the starts' velocities from finite differences
    30-45 % slow); now each start is taken from the frames after its first and its velocity
    fitted: within 10 % of 0.5 (measured 0.476 [0.424, 0.498], with warnings of a rough cost
    and of the misfit: the two engines' contact models differ, and the interval, which does
    not allow for that, misses 0.5 by 0.4 %)."""
    from dano.experiments.mujoco_c import mujoco_c_slides

    made = mujoco_c_slides(tmp_path / "toy", mesh=shared / "meshes" / "bunny_lowpoly.obj")
    _lag_every_frame_but_the_first(made["csv"])
    assert main(["sysid", str(made["toml"]), "--json", "--out-dir", str(tmp_path / "out")]) == 0
    report = json.loads(capsys.readouterr().out)
    mu, lower, upper = report["sliding_friction"], report["sliding_friction_lower"], report["sliding_friction_upper"]
    assert abs(mu / 0.5 - 1) < 0.1 and lower < mu < upper, (mu, lower, upper)
    assert any("misfits" in w for w in report["warnings"])
    assert any("a first frame may be off" in n for n in report["notes"])


def test_problems_of_one_structure_share_one_compilation():
    """Two data sets of the same lengths (different values, another initial guess): the second
    problem's residual and Jacobian reuse the first's compilation; so does a third of 3 shorter
    slides (segment counts and frame intervals are padded to buckets: 3 and 4 slides run as 4,
    17 and 19 intervals as 20), while 23 intervals (bucket 24) compile anew. (The structure of
    interval_coverage's problems: its scene, 4 slides of 20 frames, 2 substeps, initial
    positions fitted; in a run of the whole file the first problem loads that program.) The
    Jacobian, assembled from each segment's own columns, equals forward mode over all of θ."""
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.005)
    make = lambda seed, n=4, frames=20: SysIdProblem(  # noqa: E731
        scene, analytic_slides(seed, 0.05, n, frames=frames, noise=0.001),
        [FitParameter("sliding_friction", 0.2 + seed / 10, 0.0, 2.0)],
        weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=2, fit_position="xy")
    first, second, third = make(0), make(1), make(2, n=3, frames=18)
    first.residuals_and_jacobian(first.initial())
    counts, compiled = dict(_residuals_and_jacobian_jit.counts), _residuals_and_jacobian_jit._cache_size()
    r, J = second.residuals_and_jacobian(second.initial())
    r3, J3 = third.residuals_and_jacobian(third.initial() + 0.01)
    assert dict(_residuals_and_jacobian_jit.counts) == counts  # nothing traced, loaded or compiled again
    assert _residuals_and_jacobian_jit._cache_size() == compiled
    assert r.shape == (second.num_residuals,) and J.shape == (second.num_residuals, 1 + 4 * 2)  # μ, 4 × (x, y)
    assert J3.shape == (third.num_residuals, 1 + 3 * 2) and third.layout.batches[0].count == 4
    assert np.all(np.isfinite(J)) and np.any(J != 0)
    whole = np.asarray(jax.jacfwd(third.residual_function())(jnp.asarray(third.initial() + 0.01)))
    np.testing.assert_allclose(J3, whole, rtol=0, atol=1e-12 * np.abs(whole).max())
    np.testing.assert_allclose(r3, third.residual_function()(jnp.asarray(third.initial() + 0.01)), rtol=0, atol=1e-14)
    make(3, frames=24).residuals_and_jacobian(first.initial())  # another bucket: traced (or loaded) anew
    programs = lambda c: c.get("traced", 0) + c.get("loaded", 0)  # noqa: E731
    assert programs(_residuals_and_jacobian_jit.counts) == programs(counts) + 1


def test_compressed_least_squares_is_the_same_problem():
    """The residual compressed segment by segment (a thin QR per segment's block:
    JacobianBlocks.compressed) keeps the cost, JᵀJ and Jᵀr, also with per-row scales, and a
    local solve on it takes the solver's own steps on the whole residual (the same evaluations
    and estimate); a θ of the wrong length and non-finite residuals are refused. Three
    slides of 20, 18 and 15 frames (padded to 4 segments of 19 intervals), start positions
    and velocities fitted from finite differences, so every segment has start prior rows;
    the blocks' Jacobian equals forward mode over all of θ."""
    from dano.sysid.solve import solve_least_squares
    from dano.sysid.uncertainty import least_squares_functions

    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.005)
    obs = [dataclasses.replace(o, qvel0=None, time=o.time[:f], poses={"box": o.poses["box"][:f]})
           for o, f in zip(analytic_slides(5, 0.05, 3, frames=20, noise=0.001), (20, 18, 15))]
    problem = SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                           weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=2, fit_position="xy", fit_velocity="xy")
    assert len(problem.start_prior_rows.index) == 12 and problem.layout.batches[0].count == 4
    theta = problem.initial() + 0.01
    blocks = problem.jacobian_blocks(theta)
    r, J = blocks.residuals, blocks.dense()
    whole = np.asarray(jax.jacfwd(problem.residual_function())(jnp.asarray(theta)))
    np.testing.assert_allclose(J, whole, rtol=0, atol=1e-12 * np.abs(whole).max())
    scale = np.random.default_rng(0).uniform(0.5, 2.0, len(r))
    rs, Js = r * scale, J * scale[:, None]
    rc, Jc = blocks.compressed(rs, scale)
    assert Jc.shape == (4 * 5 + 1, 13) and len(r) == 2 * (19 + 17 + 14) + 12  # 4 segments × (μ + 4 offsets)
    assert abs(np.linalg.norm(rc) - np.linalg.norm(rs)) <= 1e-12 * np.linalg.norm(rs)
    np.testing.assert_allclose(Jc.T @ Jc, Js.T @ Js, rtol=0, atol=1e-12 * np.abs(Js.T @ Js).max())
    np.testing.assert_allclose(Jc.T @ rc, Js.T @ rs, rtol=0, atol=1e-12 * np.abs(Js.T @ rs).max())
    lo, hi = problem.bounds()
    fits = [solve_least_squares(f.fun, problem.initial(), lo, hi, jacobian=f.jac)
            for f in (least_squares_functions(problem, compress=c) for c in (False, True))]
    assert fits[0].nfev == fits[1].nfev and fits[0].converged and fits[1].converged
    np.testing.assert_allclose(fits[1].x, fits[0].x, rtol=0, atol=1e-9)
    assert abs(fits[1].cost - fits[0].cost) <= 1e-10 * fits[0].cost
    from dano.errors import DanoError

    with pytest.raises(DanoError, match="theta must have 13 entries"):
        problem.jacobian_blocks(theta[:5])
    with pytest.raises(ValueError, match="non-finite"):
        blocks.compressed(np.where(np.arange(len(r)) == 3, np.nan, rs))


def test_bad_interval_options_are_refused(box, tmp_path, capsys):
    from dano.errors import DanoError

    problem = SysIdProblem(box, analytic_slides(0, 0.05, 2, noise=0.0),
                           [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], substeps=4)
    with pytest.raises(DanoError, match="level"):
        identify(problem, level=1.5)
    with pytest.raises(DanoError, match="profile_points"):
        identify(problem, profile_points=3)
    obs = analytic_slides(0, 0.05, 1, noise=0.0)[0]
    np.savetxt(tmp_path / "a.csv", np.c_[obs.time, obs.poses["box"]], delimiter=",",
               header="t,x,y,z,qw,qx,qy,qz", comments="")
    box_file = tmp_path / "box.dano"
    import dano

    dano.save(box.assets[0], box_file)
    for key, value, message in (("level", "1.2", "level"), ("profile_points", "4", "profile_points")):
        toml = tmp_path / f"bad_{key}.toml"
        toml.write_text(f'[scene]\ndt = 0.0025\n[[scene.object]]\nname = "box"\nasset = "box.dano"\n'
                        f'[[trajectory]]\nfile = "a.csv"\nobject = "box"\n[[parameter]]\nname = "sliding_friction"\n'
                        f'initial = 0.3\n[options]\nsubsteps = 4\n{key} = {value}\n')
        assert main(["sysid", str(toml), "--out-dir", str(tmp_path / f"out_{key}")]) == 1
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert not (tmp_path / f"out_{key}").exists()


def test_a_segment_left_far_off_is_rescanned_and_refitted():
    """segment_restarts: four analytic Coulomb slides (closed form, not dano's), start
    velocities fitted; one slide's block is put 1.5 m/s off on each axis and held there (a
    solve of one evaluation), as a local minimum of its own would hold it. It is found as the
    one outlier (over 10x the median segment's cost), a candidate lowers its own cost, and the
    fit continued from there reaches the whole solve's answer; a converged fit is returned
    as it is, with no segment scan."""
    from dano.errors import DanoError
    from dano.sysid.solve import _local_solve, segment_restarts

    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    scene = compose([DanoObject("box", asset, (0, 0, 0.05))], dt=0.005)
    obs = [dataclasses.replace(o, qvel0=None) for o in analytic_slides(7, 0.05, 4, frames=20, noise=0.001)]
    problem = SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                           weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=2, fit_velocity="xy")
    local = dict(jacobian="ad", max_iterations=100, xtol=1e-8, ftol=None, gtol=1e-8)
    good = _local_solve(problem, problem.initial(), **local)
    assert good.success
    assert segment_restarts(problem, good, **local) is good and good.segment_scan is None
    entries = problem.segment_entries()
    assert [len(b) for _, b in entries] == [2] * 4 and sum(len(r) for r, _ in entries) == problem.num_residuals
    theta = good.estimates.copy()
    theta[entries[2][1]] += 1.5
    held = _local_solve(problem, theta, **{**local, "max_iterations": 1})
    assert held.final_cost > 10 * good.final_cost
    out = segment_restarts(problem, held, **local)
    first = out.segment_scan["rounds"][0]
    assert first["segments"] == [2] and first["moved"] == [2]
    assert first["costs"][0] > 10 * first["median_cost"]
    assert abs(out.final_cost - good.final_cost) <= 1e-6 * good.final_cost
    np.testing.assert_allclose(out.estimates, good.estimates, rtol=0, atol=1e-5)
    assert out.nfev > held.nfev and "were re-scanned" in out.notes[-1]
    with pytest.raises(DanoError, match="level"):
        segment_restarts(problem, held, level=1.5)


def test_an_answer_moved_to_a_lower_point_speaks_of_that_point(box):
    """The verification moves the answer to a lower point it evaluated where a restart's solve
    ends higher. On the real soap in windows of 16 that solve had stopped at the upper bound
    (friction 2) and the answer reported was 0.539, yet the warnings said five times that
    "sliding_friction = 2 sits at its upper bound", with no standard error. The moved answer
    now carries the point's own bound check and standard errors, and a restart carries no
    warning of the answer it replaced."""
    from dano.sysid import solve

    obs = analytic_slides(0, 0.05, 2, noise=0.001, frames=12)  # friction 0.45
    local = dict(jacobian="ad", max_iterations=50, xtol=1e-8, ftol=None, gtol=1e-8)
    fenced = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.8, 0.6, 2.0)], substeps=4)
    stuck = solve._local_solve(fenced, fenced.initial(), **local)
    assert stuck.estimates[0] == pytest.approx(0.6) and any(" sits at its lower bound" in w for w in stuck.warnings)
    assert np.isnan(stuck.standard_errors[0])

    problem = SysIdProblem(box, obs, [FitParameter("sliding_friction", 0.8, 0.0, 2.0)], substeps=4)
    moved = solve._at_point(problem, stuck, np.array([0.45]))
    assert moved.estimates[0] == 0.45 and moved.final_cost < 0.5 * float(fenced.residuals(np.array([0.6])) @
                                                                           fenced.residuals(np.array([0.6])))
    assert not any("sits at its" in w for w in moved.warnings), moved.warnings
    assert 0 < moved.standard_errors[0] < 0.05  # the curvature's, at 0.45
    assert sum("did not improve on the lowest point" in w for w in moved.warnings) == 1
    again = solve._at_point(problem, moved, np.array([0.45]))
    assert sum("did not improve on the lowest point" in w for w in again.warnings) == 1  # said once

    restart = solve._local_solve(problem, np.array([0.5]), **local)
    carried = solve._continued(stuck, restart)
    assert not any("sits at its" in w for w in carried.warnings), carried.warnings


def _t_block_slides(out: Path, friction: float) -> list[Path]:
    """A Push-T block as a user makes one: its mesh in millimetres, z up (160 mm bar and 120 mm
    stem, 40 mm wide, 30 mm thick), ``dano build`` at 0.25 kg with the defaults, ``dano export
    --collision decomposition`` (CoACD: the two boxes); then three plain MuJoCo C slides (2 ms
    steps, elliptic cone, ``friction`` on both geoms), each set moving and spinning at once from
    rest (``data.qvel``: about 1 m/s, 4–8 rad/s), recorded from ``qpos`` at 100 Hz for 0.6 s
    as ``t_k.csv``. Writes tblock.obj, tblock.dano, tblock.xml."""
    import mujoco
    import trimesh

    bar, stem = trimesh.creation.box([160, 40, 30]), trimesh.creation.box([40, 120, 30])
    bar.apply_translation([0, 60, 15])
    stem.apply_translation([0, -20, 15])
    trimesh.boolean.union([bar, stem], engine="manifold").export(out / "tblock.obj")
    assert main(["build", str(out / "tblock.obj"), "-o", str(out / "tblock.dano"), "--scale", "0.001",
                 "--mass", "0.25"]) == 0
    assert main(["export", str(out / "tblock.dano"), "-o", str(out / "tblock.xml"), "--collision",
                 "decomposition"]) == 0
    spec = mujoco.MjSpec.from_file(str(out / "tblock.xml"))
    spec.option.timestep, spec.option.cone = 0.002, mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 1], friction=[friction, 0.005, 0.0001])
    for geom in spec.geoms:
        geom.friction = [friction, 0.005, 0.0001]
    model = spec.compile()
    data = mujoco.MjData(model)
    files = []
    for k, (vx, vy, wz) in enumerate([(1.0, 0.2, 4.0), (-0.7, 0.8, -6.0), (0.3, -0.9, 8.0)]):
        mujoco.mj_resetData(model, data)
        data.qpos[2] = 0.03
        while data.time < 1.0:  # settle on the floor
            mujoco.mj_step(model, data)
        data.qvel[:3], data.qvel[5] = [vx, vy, 0.0], wz
        files.append(_record_csv(model, data, out / f"t_{k + 1}.csv", frames=60))
    return files


@pytest.mark.slow
def test_mujoco_slides_that_hop_at_the_start_are_started_from_their_first_frames(tmp_path):
    """A Push-T block set sliding and spinning at once in plain MuJoCo C (friction 0.8): MuJoCo's
    contact hops in the first step (the block loses 0.09 m/s in 2 ms and leaves the floor), so
    the first three frames disagree with the parabola through the next four by 21 % of the speed,
    twice what the frames after them do: taken as a first frame that is off. It is not: the
    first frames' velocity is MuJoCo's after that step (0.913 against 0.910 m/s), the next
    frames' parabola is 17 % off, and with it and the start velocities fitted the defaults said
    0.698 [0.694, 0.703] (measured 2026-12-02). The scan, started from the first frames, fits
    better (its lowest cost about half), so the identification starts there, says so, and its
    interval holds MuJoCo's 0.8 (measured: 0.775 [0.697, 0.872]). With the first frames moved
    2 mm back (a first frame that is off) the next frames' start is kept. The scan the
    comparison ran is the identification's own (not run again)."""
    from dano.sysid.config import problem_from_toml, template

    _t_block_slides(tmp_path, 0.8)
    text = template([str(tmp_path / "tblock.dano")])
    block = text[text.index("[[trajectory]]"):text.index("[[parameter]]")]
    text = text.replace(block, "".join(block.replace("tblock_1.csv", f"t_{k}.csv") for k in (1, 2, 3)))
    (tmp_path / "problem.toml").write_text(text)
    problem = problem_from_toml(tmp_path / "problem.toml")[0]
    assert problem.start_velocity == "next frames" and problem.fit_velocity == "xyz"
    # the same slides with their first frames 2 mm back along the motion (a pose read a substep
    # apart): the first frames' start fits worse, and the next frames' is kept, its scan handed on
    off = dataclasses.replace(problem, observations=[_first_frame_off(o, "tblock", 0.002)
                                                     for o in problem.observations])
    kept, scanned = _first_frames_if_they_fit(off, 15)
    assert kept is off and kept.start_velocity == "next frames" and np.all(np.isfinite(scanned[0][0]))
    result = identify(problem)
    (note,) = [n for n in result.notes if "fit better" in n]
    assert 'start_velocity = "first frames"' in note
    assert not any(n.startswith("start velocities (fit_velocity auto)") for n in result.notes)
    assert not any("a first frame may be off" in w for w in result.warnings)  # (the first frames were chosen)
    answer = problem.as_identified(result)  # (the problem the estimates belong to)
    assert result.as_dict()["start_velocity"] == answer.start_velocity == "first frames"
    assert answer.fit_velocity == "" and len(result.estimates) == answer.num_parameters == 1
    # the comparison's first-frames scan (with the offsets at 0) is the answer problem's own scan
    costs = _scan(answer, np.asarray(result.scan["points"]))[0]
    np.testing.assert_allclose(costs, result.scan["cost"], rtol=1e-12)
    lower, upper = result.interval["lower"]["sliding_friction"], result.interval["upper"]["sliding_friction"]
    assert lower < 0.8 < upper, (result.estimates[0], lower, upper)
