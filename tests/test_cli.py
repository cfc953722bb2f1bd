"""The command line: build, inspect, demo; bad input exits non-zero with a clear message
and leaves no output file."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dano.cli import main

from .conftest import sphere_voxels


def run(capsys, *args):
    code = main([str(a) for a in args])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


def test_build_voxel_then_inspect_json_and_plot(tmp_path, capsys):
    src = sphere_voxels(tmp_path / "ball.npz")
    out = tmp_path / "ball.dano"
    code, _, err = run(capsys, "build", src, "-o", out, "--mass", 2.0, "--samples", 500, "--quiet", "--name", "ball_2")
    assert code == 0, err
    from dano.asset import load

    assert load(out).name == "ball_2"  # (--name; default: the source's stem, "ball")
    code, stdout, err = run(capsys, "inspect", out, "--json", "--plot", tmp_path / "ball.png")
    assert code == 0, err
    s = json.loads(stdout)
    assert s["mass"] == pytest.approx(2.0)
    assert s["num_samples"] == 500 and s["normals_valid_fraction"] == 1.0
    assert np.allclose(s["center_of_mass"], 0.0, atol=2e-3)
    J = np.array(s["inertia"])
    assert np.allclose(J, J.T) and np.allclose(J, J[0, 0] * np.eye(3), rtol=0.01, atol=1e-4)
    assert len(s["band"]) == 2 and (tmp_path / "ball.png").stat().st_size > 10_000
    # build --json: the same summary as inspect's, the file and the times
    code, stdout, err = run(capsys, "build", src, "-o", tmp_path / "b2.dano", "--mass", 2.0, "--samples", 500,
                            "--name", "ball_2", "--json")
    assert code == 0, err
    built = json.loads(stdout)
    assert built["file"] == str(tmp_path / "b2.dano") and built["calibration"] is None
    assert built["mass"] == s["mass"] and built["inertia"] == s["inertia"]
    assert isinstance(built["compile_time_s"], float) and isinstance(built["wall_time_s"], float)


def test_build_paper_collider_with_mass(tmp_path, capsys, shared):
    out = tmp_path / "bunny.dano"
    code, _, err = run(capsys, "build", shared / "dano" / "bunny.jld2", "-o", out, "--mass", 1.0, "--quiet")
    assert code == 0, err
    code, stdout, _ = run(capsys, "inspect", out, "--json")
    s = json.loads(stdout)
    assert s["mass"] == pytest.approx(1.0) and s["num_samples"] == 5000
    assert np.allclose(s["center_of_mass"], [0.03746, -0.01419, -0.04771], atol=5e-6)


def _bad_jld2(tmp_path, shared):
    p = tmp_path / "trunc.jld2"
    p.write_bytes((shared / "dano" / "bunny.jld2").read_bytes()[:5000])
    return p


def _nan_voxels(tmp_path, shared):
    p = tmp_path / "nan.npz"
    d = np.ones((4, 4, 4))
    d[1, 2, 3] = np.nan
    np.savez(p, density=d, bounds=np.array([[0, 0, 0], [1, 1, 1.0]]))
    return p


def _negative_voxels(tmp_path, shared):
    p = tmp_path / "neg.npz"
    np.savez(p, density=-np.ones((4, 4, 4)), bounds=np.array([[0, 0, 0], [1, 1, 1.0]]))
    return p


def _wrong_shape_voxels(tmp_path, shared):
    p = tmp_path / "flat.npz"
    np.savez(p, density=np.ones((4, 4)), bounds=np.array([[0, 0, 0], [1, 1, 1.0]]))
    return p


@pytest.mark.parametrize(
    "make_source, extra, message",
    [
        (lambda t, s: s / "dano" / "bunny_low.obj", [], "bunny_low.obj: mesh is not watertight"),
        (lambda t, s: sphere_voxels(t / "v.npz"), ["--band", 5, 6], r"no samples in the density band \[5, 6\]"),
        (_nan_voxels, [], "nan.npz: voxel densities contains 1 NaN"),
        (_negative_voxels, [], "neg.npz: voxel densities must be non-negative"),
        (_wrong_shape_voxels, [], r"flat.npz: voxel densities must be a 3-D array"),
        (_bad_jld2, [], "trunc.jld2: cannot read as a JLD2/HDF5 file"),
        (lambda t, s: s / "dano" / "bluesoap.jld2", [], "stored density gradients are zero"),
        (lambda t, s: t / "missing.obj", [], "missing.obj: no such file"),
        (lambda t, s: s / "real" / "soap_pose_traj.csv", [], "unknown source type '.csv'"),
        (lambda t, s: s / "meshes" / "spot.obj", ["--mass", -0.7], "--mass must be a finite positive number"),
        (lambda t, s: s / "meshes" / "spot.obj", ["--size", 0], "--size must be a finite positive number"),
    ],
)
def test_bad_input_clear_error_and_no_output(tmp_path, capsys, shared, make_source, extra, message):
    src = make_source(tmp_path, shared)
    out = tmp_path / "out" / "x.dano"
    code, _, err = run(capsys, "build", src, "-o", out, "--quiet", *extra)
    assert code != 0
    assert "error:" in err
    import re

    assert re.search(message, " ".join(err.split())), err
    assert not out.exists()
    assert not list(tmp_path.glob("out/*"))


def test_inspect_other_version_and_bad_file(tmp_path, capsys, shared):
    p = tmp_path / "x.dano"
    p.write_text("nope")
    code, _, err = run(capsys, "inspect", p)
    assert code == 1 and "x.dano: not a .dano file" in err
    # a source given where a .dano is expected: how to build one, not NumPy's words about pickles
    mesh = shared / "meshes" / "spot.obj"
    code, _, err = run(capsys, "inspect", mesh)
    err = " ".join(err.split())
    assert code == 1 and "spot.obj: not a .dano file" in err and f"dano build {mesh} -o NAME.dano" in err
    assert "pickle" not in err
    # an image format matplotlib cannot write: refused before the work (no table printed)
    code, out, err = run(capsys, "inspect", "builtin:bunny", "--plot", tmp_path / "s.jpgg")
    assert code == 1 and "s.jpgg: --plot: cannot write an image as .jpgg" in " ".join(err.split()) and not out


def test_an_error_is_one_line_with_the_progress_bars_on(tmp_path, capsys):
    """Without --quiet, where standard error is not a terminal (a log, a pipe), the error is
    its first line: no bar, and no blank line where the bar was."""
    code, _, err = run(capsys, "build", tmp_path / "missing.obj", "-o", tmp_path / "x.dano")
    assert code == 1 and err.startswith("error: ") and err.count("\n") == 1, repr(err)


def test_parse_errors_exit_non_zero(capsys):
    assert main(["build"]) != 0
    assert main(["frobnicate"]) != 0


@pytest.mark.slow  # end to end, 23 s cold (the README's install command runs the demo too)
def test_demo_and_console_script(tmp_path):
    beside = Path(sys.executable).with_name("dano")  # the venv's script, even if not on PATH
    exe = str(beside) if beside.exists() else shutil.which("dano")
    if exe is None:
        pytest.fail("the dano console script is not installed")
    res = subprocess.run([exe, "demo", "--out-dir", str(tmp_path)], capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr
    assert "3.21985" in res.stdout
    summary = json.loads((tmp_path / "summary.json").read_text())
    assert summary["asset"]["num_samples"] == 5000
    assert summary["final_overlap"] == pytest.approx(summary["rest_overlap_mg_over_k"], rel=0.1)
    assert 0.25 < summary["final_center_of_mass"][2] < 0.55
    assert (tmp_path / "bunny_samples.png").stat().st_size > 10_000
    assert (tmp_path / "bunny-drop.mp4").stat().st_size > 10_000
    assert np.load(tmp_path / "bunny-drop.npz")["qpos"].shape == (501, 7)
    res = subprocess.run([sys.executable, "-m", "dano.cli", "--version"], capture_output=True, text=True)
    assert res.returncode == 0 and res.stdout.startswith("dano ")
    # the console script exits with main's code (cli.console_main), an error as one line
    res = subprocess.run([exe, "sysid", "no-such-problem"], capture_output=True, text=True, timeout=600)
    assert res.returncode == 1 and res.stderr.startswith("error: unknown identification 'no-such-problem'")
    assert "Traceback" not in res.stderr


@pytest.mark.slow  # a benchmark suite: 11 s cold
def test_energy_benchmark_json_contract(capsys, tmp_path):
    # `dano bench --suite energy --json --drops N` prints the keys others script against
    out = tmp_path / "energy.json"
    assert main(["bench", "--suite", "energy", "--json", "--drops", "3", "--seed", "2", "--out", str(out)]) == 0
    report = json.loads(capsys.readouterr().out)["energy"]
    assert {"drops", "nonfinite", "diverged", "energy_rises", "max_energy_ratio", "seed"} <= set(report)
    assert report["drops"] == 3 and report["seed"] == 2
    assert (report["nonfinite"], report["diverged"], report["energy_rises"]) == (0, 0, 0)
    assert json.loads(out.read_text())["energy"]["drops"] == 3
    assert main(["bench", "--suite", "energy", "--drops", "0"]) != 0  # a clear error, not a traceback
    assert "drops" in capsys.readouterr().err


def test_scaling_benchmark_reports_a_point_past_its_time_and_goes_on(capsys):
    # each point runs in its own process: one that runs too long (on a GPU: the float32
    # batches that sometimes never finished, docs/scaling.md) is reported, not waited for
    from dano.bench import bench_scaling

    r = bench_scaling(batches=(4, 4), dtypes=("float32",), engines=("dano",), timeout_s=1.0)
    for key in ("dano_float32_4", "dano_float32_4_2"):  # a B given twice: two attempts
        assert r[key]["timed_out_s"] == 1.0 and r[key]["wall_s"] < 30
    assert "ratio_dano_over_mjx_float32_4" not in r
    assert main(["bench", "--suite", "scaling", "--batches", "0"]) != 0
    assert "--batches" in capsys.readouterr().err


def test_a_scaling_point_runs_with_the_environment_given(tmp_path):
    # scripts/gpu_session.py --baseline times an earlier dano by putting its src first on the
    # point process's PYTHONPATH: here a "dano" that fails at import shows whose code ran
    from dano.bench import scaling_point_in_process

    (tmp_path / "dano").mkdir()
    (tmp_path / "dano" / "__init__.py").write_text("raise ImportError('the baseline ran')\n")
    r = scaling_point_in_process(60, env={"PYTHONPATH": str(tmp_path)}, engine="dano", dtype="float32", batch=4)
    assert "the baseline ran" in " ".join(r["error"]), r


@pytest.mark.slow  # a benchmark suite: four processes, ~35 s
def test_scaling_benchmark_keys():
    from dano.bench import bench_scaling

    r = bench_scaling(repeats=1, steps=20, batches=(4,), timeout_s=600)
    for engine in ("dano", "mjx"):
        for dtype in ("float32", "float64"):
            p = r[f"{engine}_{dtype}_4"]
            assert (p["engine"], p["dtype"], p["batch"], p["steps"]) == (engine, dtype, 4, 20), p
            assert p["env_steps_per_s"] > 0 and p["non_finite_envs"] == 0 and p["max_rss_bytes"] > 0
    for dtype in ("float32", "float64"):
        p = r[f"dano_{dtype}_4"]
        # the vmapped Newton loop runs at least as many iterations as the median env needs
        assert p["loop_trips"] >= p["typical_env_trips"] >= 20 and p["envs_at_max"] == 0
        assert r[f"ratio_dano_over_mjx_{dtype}_4"] > 0


@pytest.mark.slow  # a benchmark suite: 41 s cold
def test_sim_benchmark_keys_and_interleaved_ratios(monkeypatch):
    # the sim suite's keys (benchmarks/README.md) with a few steps; its ratios are medians of
    # the ratios within each round of interleaved timings
    from dano.bench import bench_sim

    monkeypatch.delenv("MENAGERIE_ROOT", raising=False)
    r = bench_sim(repeats=3, steps=20, mujoco_steps=200)
    for key in ("bunny_drop", "bunny_drop_per_sample", "bunny_drop_float32", "bunny_drop_lapack",
                "bunny_drop_untouched_primitives", "mujoco_c_convex_hull"):
        assert r[key]["repeats"] == 3 and 0 < r[key]["min_s"] <= r[key]["median_s"]
        assert r[key]["steps_per_s"] > 0
    assert r["bunny_drop"]["contact_model"] == "centroid" and r["bunny_drop"]["num_samples"] == 5000
    assert r["ratio_per_sample_over_centroid_time"] > 0 and r["ratio_dano_over_mujoco_c"] > 0
    # 20 steps are too few for the unrolled solve (NewtonConfig.linear_solver="auto")
    assert r["bunny_drop"]["linear_solver"] == r["bunny_drop_lapack"]["linear_solver"] == "lapack"
    assert r["ratio_lapack_over_default_time"] > 0 and r["ratio_untouched_primitives_over_drop_time"] > 0
    assert r["sphere_hits_bunny"]["steps_per_s"] > 0 and r["ratio_sphere_hits_over_drop_time"] > 0
    # objects sliding on a face: the box's per-sample pair has room for its face, the _64 one not
    for key in ("bunny_slide", "bunny_slide_per_sample", "box_slide", "box_slide_per_sample",
                "box_slide_per_sample_64"):
        assert r[key]["steps_per_s"] > 0
    assert r["box_slide_per_sample"]["max_active"] == 1536 and r["box_slide_per_sample_64"]["max_active"] == 64
    for key in ("ratio_per_sample_over_centroid_time_slide", "ratio_per_sample_over_centroid_time_box",
                "ratio_box_per_sample_64_over_sized_time"):
        assert r[key] > 0
    assert r["panda_push_bunny"].startswith("skipped")
    assert r["jacfwd_200"]["parameters"] == ["sliding_friction", "alpha"]


def test_bad_inputs_of_the_image_route_and_build_say_what_is_wrong(tmp_path, capsys, shared):
    """Found by a new user's run (2026-11-26): each is refused in one line before any work,
    naming the file or option, with nothing written."""
    code, _, err = run(capsys, "build", shared / "meshes" / "spot.obj", "-o", tmp_path / "x.dano", "--name", "a/b")
    assert code == 1 and "--name 'a/b': letters, digits" in " ".join(err.split())
    code, _, err = run(capsys, "build", shared / "meshes" / "spot.obj", "-o", tmp_path)  # a folder as the output
    assert code == 1 and f"-o {tmp_path}: is a folder" in " ".join(err.split())
    assert not list(tmp_path.iterdir())
    fake = tmp_path / "views.npz"
    fake.write_text("x")
    code, _, err = run(capsys, "train-field", fake, "-o", tmp_path / "f")
    err = " ".join(err.split())
    assert code == 1 and "views.npz: cannot read image set (not an npz archive)" in err and "pickle" not in err
    views = tmp_path / "views"
    views.mkdir()
    (views / "transforms.json").write_text('{"frames": []}')
    code, _, err = run(capsys, "train-field", views, "-o", tmp_path / "f")
    assert code == 1 and 'the "frames" list is empty' in err
    code, _, err = run(capsys, "train-field", views, "-o", tmp_path / "f", "--minutes", 0.2, "--eval-at", 0.1, 1)
    assert code == 1 and "--eval-at 1: after the end of the run (--minutes 0.2)" in " ".join(err.split())
    assert not (tmp_path / "f").exists()


def test_library_deprecations_are_not_printed_to_the_user(tmp_path, capsys, monkeypatch):
    """A command prints the warnings meant for its user (here a UserWarning), not a library's
    deprecations, which speak to developers: under NumPy 2.5 scikit-image's marching cubes
    raised one, and `dano build` printed it as its own warning."""
    import warnings

    import dano.experiments

    def command(c):
        warnings.warn("np.array.shape setter is deprecated", DeprecationWarning)
        warnings.warn("the scan saw a lower cost", UserWarning)
        return None, None, {"warnings": [], "estimates": {}}, tmp_path

    monkeypatch.setattr(dano.experiments, "sysid_command", command)
    code, _, err = run(capsys, "sysid", "problem.toml", "--json")
    err = " ".join(err.split())
    assert code == 0 and "UserWarning: the scan saw a lower cost" in err and "deprecated" not in err, err


def test_warnings_are_printed_as_written_not_as_markup(tmp_path, capsys, monkeypatch):
    """A warning that names a TOML table ("[options] window") reaches the terminal whole: the
    console's markup would take "[options]" for a style and drop it."""
    import dano.experiments

    note = "windows ([options] window or auto_windows) or more trajectories smooth the cost"
    monkeypatch.setattr(dano.experiments, "sysid_command",
                        lambda c: (None, None, {"warnings": [note], "estimates": {}}, tmp_path))
    code, out, err = run(capsys, "sysid", "problem.toml", "--json")
    assert code == 0 and f"problem.toml: {note}" in " ".join(err.split()), err
