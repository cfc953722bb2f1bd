"""Generated bad input across the command line (hypothesis): every run ends with exit code
0, 1 or 2, never with a traceback or an internal error, leaves no output or temporary file
behind when it fails, and what is accepted is physically valid.

Each property test tries 25 inputs; the slow-marked ``test_fuzz_run_counts`` (part of the
normal run too) tries about 1,100 more and, with ``-s``, prints the counts per verb."""

import json
import os
import shutil
import tempfile
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from dano.asset import build, load, save
from dano.cli import main
from dano.fields import BoxField

COUNTS: Counter = Counter()
FAST = settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
SLOW = settings(max_examples=120, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])


def run_cli(capsys, verb: str, args: list, folder: Path, outputs: list[Path]) -> int:
    before = set(os.listdir(folder))
    code = main([verb, *map(str, args)])
    err = capsys.readouterr().err
    assert code in (0, 1, 2), (args, err)
    assert "internal error" not in err and "Traceback" not in err, (args, err)
    assert not (folder / "MUJOCO_LOG.TXT").exists()
    if code != 0:
        assert set(os.listdir(folder)) == before, (args, err)  # nothing written, no temporary file
        assert all(not p.exists() for p in outputs)
    COUNTS[verb, "accepted" if code == 0 else "refused"] += 1
    return code


def assert_physical(asset) -> None:
    assert asset.mass > 0 and asset.alpha > 0 and np.isfinite(asset.mass)
    assert abs(asset.weights.sum() - asset.mass) <= 1e-6 * asset.mass
    moments = np.linalg.eigvalsh(asset.inertia)
    assert moments[0] > 0 and moments[0] + moments[1] >= moments[2] * (1 - 1e-6)
    assert np.all(np.abs(np.linalg.norm(asset.normals, axis=1) - 1) < 1e-6)
    assert np.all(np.isfinite(asset.points)) and asset.band[0] < asset.band[1]


@pytest.fixture(scope="module")
def good_dano(tmp_path_factory):
    path = tmp_path_factory.mktemp("fuzz") / "box.dano"
    save(build(BoxField((0.05, 0.04, 0.03)), mass=0.5, num_samples=200, integration_points=1 << 14,
               mesh_resolution=12, name="box"), path)
    return path


_ARRAYS = ["center_of_mass", "inertia", "points", "normals", "densities", "weights", "band", "mesh_vertices",
           "mesh_faces", "field/spec"]
_EDITS = ["nan", "inf", "negate", "scale_huge", "zero", "drop_row", "transpose", "delete", "float_noise"]


def _edit(a: np.ndarray, how: str, rng):
    a = np.array(a)
    if a.dtype.kind in "US":
        return np.asarray({"nan": "[1]", "inf": "{", "negate": "null", "zero": "0"}.get(how, '{"kind": "torus"}'))
    if a.size == 0:
        return np.ones((2, 3))
    flat = a.astype(np.float64).ravel()
    i = int(rng.integers(flat.size))
    if how == "nan":
        flat[i] = np.nan
    elif how == "inf":
        flat[i] = np.inf
    elif how == "negate":
        flat = -flat
    elif how == "scale_huge":
        flat = flat * 1e200
    elif how == "zero":
        flat[:] = 0
    elif how == "float_noise":
        flat[i] += 0.37
    out = flat.reshape(a.shape)
    if how == "drop_row" and out.ndim >= 1 and len(out) > 1:
        out = out[:-1]
    if how == "transpose" and out.ndim == 2:
        out = out.T
    return out


def _corrupt_dano(src: Path, dst: Path, key: str, how: str, seed: int) -> None:
    rng = np.random.default_rng(seed)
    with np.load(src) as d:
        arrays = {k: d[k] for k in d.files}
    if key == "metadata":
        meta = json.loads(str(arrays["metadata"]))
        field = ["mass", "alpha", "version", "format", "name"][seed % 5]
        meta[field] = [None, "x", -1.0, float("nan"), [1], {"a": 1}, 1e300, 0][seed % 8]
        arrays["metadata"] = np.asarray(json.dumps(meta))
    elif how == "delete":
        arrays.pop(key, None)
    else:
        arrays[key] = _edit(arrays[key], how, rng)
    with open(dst, "wb") as f:
        np.savez(f, **arrays)


def fuzz_dano(capsys, good_dano, key, how, seed):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bad = folder / "in.dano"
        _corrupt_dano(good_dano, bad, key, how, seed)
        accepted = run_cli(capsys, "inspect", [bad, "--json"], folder, []) == 0
        if accepted:
            assert_physical(load(bad))
        out = folder / "out.xml"
        run_cli(capsys, "export", [bad, "-o", out, "--collision", "none"], folder, [out])
        if not accepted:  # (an accepted file would run a whole comparison: minutes)
            report = folder / "r.json"
            assert run_cli(capsys, "compare-mesh", [bad, "--out", report, "--quiet"], folder, [report]) == 1


S_DANO = dict(key=st.sampled_from(_ARRAYS + ["metadata"]), how=st.sampled_from(_EDITS), seed=st.integers(0, 10**6))


@FAST
@given(**S_DANO)
def test_corrupted_dano_files(capsys, good_dano, key, how, seed):
    fuzz_dano(capsys, good_dano, key, how, seed)


_JLD2_KEYS = ["mass", "inertia", "center_of_mass", "densities"]


def fuzz_jld2(capsys, shared, key, how, seed):
    import h5py

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bad = folder / "in.jld2"
        shutil.copy(shared / "dano" / "bunny.jld2", bad)
        with h5py.File(bad, "r+") as f:
            if key == "particles":
                p = f["particles"][()]
                p[seed % len(p)]["data"]["1"] = [13000.0, np.nan, 1e200, -5.0][seed % 4]
                f["particles"][...] = p
            else:
                a = np.atleast_1d(f[key][()]).astype(np.float64)
                new = _edit(a, how, np.random.default_rng(seed)).astype(np.float64)
                if new.shape == a.shape:
                    f[key][...] = new.reshape(f[key].shape)
                else:
                    del f[key]
                    f[key] = new
        out = folder / "out.dano"
        if run_cli(capsys, "build", [bad, "-o", out, "--quiet"], folder, [out]) == 0:
            assert_physical(load(out))


S_JLD2 = dict(key=st.sampled_from(_JLD2_KEYS + ["particles"]), how=st.sampled_from(_EDITS[:-2]),
              seed=st.integers(0, 10**6))


@FAST
@given(**S_JLD2)
def test_corrupted_paper_colliders(capsys, shared, key, how, seed):
    fuzz_jld2(capsys, shared, key, how, seed)


def fuzz_mesh(capsys, shared, suffix, cut, garbage):
    src = {".obj": shared / "meshes" / "bunny_lowpoly.obj", ".stl": shared / "dano" / "bluesoap_level_100.obj"}
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        data = src[suffix].read_bytes()
        if suffix == ".stl":
            import trimesh

            data = trimesh.load(src[suffix], force="mesh").export(file_type="stl")
        bad = folder / f"in{suffix}"
        bad.write_bytes(data[: int(cut * len(data))] + garbage)
        out = folder / "out.dano"
        if run_cli(capsys, "build", [bad, "-o", out, "--resolution", 16, "--samples", 50, "--quiet"], folder,
                   [out]) == 0:
            assert_physical(load(out))


S_MESH = dict(suffix=st.sampled_from([".obj", ".stl"]), cut=st.floats(0.0, 0.98), garbage=st.binary(max_size=40))


@FAST
@given(**S_MESH)
def test_truncated_meshes(capsys, shared, suffix, cut, garbage):
    fuzz_mesh(capsys, shared, suffix, cut, garbage)


def fuzz_voxels(capsys, shape, value, bounds):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        bad = folder / "grid.npz"
        arrays = {"density": np.full(shape, value)}
        if bounds is not None:
            arrays["bounds"] = np.asarray(bounds, dtype=float)
        np.savez(bad, **arrays)
        out = folder / "out.dano"
        if run_cli(capsys, "build", [bad, "-o", out, "--samples", 50, "--quiet"], folder, [out]) == 0:
            assert_physical(load(out))


S_VOXELS = dict(shape=st.sampled_from([(0,), (4, 4), (1, 1, 1), (3, 3, 3), (2, 2, 2, 2)]),
                value=st.sampled_from([0.0, -1.0, np.nan, np.inf, 1.0]),
                bounds=st.sampled_from([None, [[1, 1, 1], [0, 0, 0]], [[0, 0, 0], [0, 0, 0]], [[0, 0], [1, 1]],
                                        [[0, 0, np.nan], [1, 1, 1]], [[-1, -1, -1], [1, 1, 1]]]))


@FAST
@given(**S_VOXELS)
def test_bad_voxel_grids(capsys, shape, value, bounds):
    fuzz_voxels(capsys, shape, value, bounds)


_TOML_KEYS = ["scene.dt", "scene.object", "scene.contact_model", "trajectory", "parameter", "options.substeps",
              "options.fit_velocity", "options.horizons", "options.window", "options.position_weights",
              "options.jacobian", "contact.sliding_drag", "parameter.0.lower", "parameter.0.initial",
              "trajectory.0.file", "scene.object.0.pos", "extra"]
_TOML_VALUES = ["7", '"0.4"', "0", "-1", "true", "[]", "[1, 2]", '{ a = 1 }', "nan", "inf", '"xyz"', "1e400"]


def _valid_config(folder: Path, good_dano: Path) -> dict:
    shutil.copy(good_dano, folder / "box.dano")
    t = np.arange(5) * 0.01
    rows = np.column_stack([t, 0.1 * t, 0 * t, 0.03 + 0 * t, 1 + 0 * t, 0 * t, 0 * t, 0 * t])
    np.savetxt(folder / "slide.csv", rows, delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")
    return {"scene": {"dt": 0.01, "object": [{"name": "box", "asset": "box.dano", "pos": [0, 0, 0.03]}]},
            "contact": {"sliding_drag": 0.0}, "trajectory": [{"file": "slide.csv", "object": "box"}],
            "parameter": [{"name": "sliding_friction", "initial": 0.3, "lower": 0.0, "upper": 2.0}],
            "options": {"substeps": 1}}


def _toml(value) -> str:
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml(v)}" for k, v in value.items()) + " }"
    if isinstance(value, list):
        return "[" + ", ".join(_toml(v) for v in value) + "]"
    return json.dumps(value)  # strings and numbers: JSON's spelling is TOML's


def _dump(cfg: dict) -> str:
    return "\n".join(f"{k} = {_toml(v)}" for k, v in cfg.items())


def fuzz_toml(key, raw, capsys=None):
    from dano.errors import DanoError
    from dano.sysid.config import SysIdConfig, read_config

    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        cfg = _valid_config(folder, Path(os.environ["DANO_FUZZ_DANO"]))
        node, parts = cfg, key.split(".")
        for p in parts[:-1]:
            node = node[int(p)] if p.isdigit() else node[p]
        last = parts[-1]
        marker = "__FUZZ__"
        if isinstance(node, list):
            node[int(last)] = marker
        else:
            node[last] = marker
        text = _dump(cfg).replace(json.dumps(marker), raw)
        path = folder / "p.toml"
        path.write_text(text)
        try:
            c = read_config(path)
        except DanoError as exc:
            assert str(path) in str(exc)
            COUNTS["sysid-config", "refused"] += 1
            if capsys is not None:  # and the command line says so, writing nothing
                out_dir = folder / "out"
                assert run_cli(capsys, "sysid", [path, "--out-dir", out_dir], folder, [out_dir]) == 1
            return
        assert isinstance(c, SysIdConfig)  # accepted: built, so its __post_init__ checked every value
        COUNTS["sysid-config", "accepted"] += 1


S_TOML = dict(key=st.sampled_from(_TOML_KEYS), raw=st.sampled_from(_TOML_VALUES))


@FAST
@given(**S_TOML)
def test_bad_sysid_configurations(capsys, good_dano, key, raw, monkeypatch):
    monkeypatch.setenv("DANO_FUZZ_DANO", str(good_dano))
    fuzz_toml(key, raw, capsys)


@pytest.fixture(scope="module")
def box_scene(good_dano):
    from dano.sim import DanoObject, compose

    return compose([DanoObject("box", load(good_dano), (0, 0, 0.03))], dt=0.01)


_CSV_EDITS = ["drop_header_column", "text_cell", "nan_cell", "repeat_time", "cut_line", "empty", "header_only",
              "huge_cell", "extra_cell", "semicolons", "mm_positions"]


def fuzz_csv(box_scene, how, row, col):
    from dano.errors import DanoError
    from dano.sysid.config import _read_observation
    from dano.sysid.problem import _check_observation

    t = np.arange(8) * 0.01
    rows = np.column_stack([t, 0.1 * t, 0 * t, 0.03 + 0 * t, 1 + 0 * t, 0 * t, 0 * t, 0 * t])
    lines = ["t,x,y,z,qw,qx,qy,qz"] + [",".join(repr(float(v)) for v in r) for r in rows]
    r, c = 1 + row % (len(lines) - 1), col % 8
    cells = lines[r].split(",")
    if how == "drop_header_column":
        lines[0] = ",".join(lines[0].split(",")[:c] + lines[0].split(",")[c + 1:])
    elif how in ("text_cell", "nan_cell", "huge_cell"):
        cells[c] = {"text_cell": "abc", "nan_cell": "nan", "huge_cell": "1e300"}[how]
        lines[r] = ",".join(cells)
    elif how == "repeat_time":
        lines[r] = ",".join([lines[r - 1].split(",")[0]] + cells[1:]) if r > 1 else lines[r]
    elif how == "cut_line":
        lines = lines[:r] + [lines[r][: len(lines[r]) // 2]]
    elif how == "empty":
        lines = []
    elif how == "header_only":
        lines = lines[:1]
    elif how == "extra_cell":
        lines[r] += ",7"
    elif how == "semicolons":
        lines = [x.replace(",", ";") for x in lines]
    elif how == "mm_positions":
        lines = lines[:1] + [",".join([x.split(",")[0]] + [repr(float(v) * 1000) for v in x.split(",")[1:4]]
                                      + x.split(",")[4:]) for x in lines[1:]]
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "obs.csv"
        path.write_text("\n".join(lines) + "\n")
        try:
            obs = _read_observation(path, "box", box_scene)
            _check_observation(obs, box_scene, 0)
        except DanoError as exc:
            assert "obs.csv" in str(exc), str(exc)
            COUNTS["sysid-csv", "refused"] += 1
            return
        COUNTS["sysid-csv", "accepted"] += 1


S_CSV = dict(how=st.sampled_from(_CSV_EDITS), row=st.integers(0, 100), col=st.integers(0, 100))


@FAST
@given(**S_CSV)
def test_bad_trajectory_csv(box_scene, how, row, col):
    fuzz_csv(box_scene, how, row, col)


_OPTION_VALUES = ["0", "-1", "inf", "nan", "1e400", "abc", "", "1e9", "1e-9"]


def fuzz_simulate(capsys, option, value):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        out, video = folder / "t.npz", folder / "v.mp4"
        args = ["bunny-drop", f"--{option}", value, "--out", out, "--max-steps", 2, "--quiet"]
        if option == "fps":
            args += ["--video", video]
        if option == "param":
            args[1:3] = ["--param", f"sliding_friction={value}"]
        run_cli(capsys, "simulate", args, folder, [out, video])


S_SIM = dict(option=st.sampled_from(["duration", "dt", "fps", "param"]), value=st.sampled_from(_OPTION_VALUES))


@FAST
@given(**S_SIM)
def test_bad_simulate_options(capsys, option, value):
    fuzz_simulate(capsys, option, value)


def fuzz_bench(capsys, option, value):
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        out = folder / "b.json"
        args = ["--suite", "energy", f"--{option}", value, "--out", out]
        if option == "suite":
            args = ["--suite", value, "--out", out]
        assert run_cli(capsys, "bench", args, folder, [out]) in (1, 2)


S_BENCH = dict(option=st.sampled_from(["drops", "repeats", "suite", "contact-model", "batches", "scaling-timeout"]),
               value=st.sampled_from(["0", "-3", "1e9", "x", "", "10000000", "simulation"]))


@FAST
@given(**S_BENCH)
def test_bad_bench_options(capsys, option, value):
    fuzz_bench(capsys, option, value)


@pytest.mark.slow
def test_fuzz_run_counts(capsys, good_dano, shared, box_scene, monkeypatch):
    """The larger run (≥ 300 generated inputs across all verbs); prints the counts."""
    monkeypatch.setenv("DANO_FUZZ_DANO", str(good_dano))
    COUNTS.clear()
    for test, strategies in [
        (lambda **kw: fuzz_dano(capsys, good_dano, **kw), S_DANO),
        (lambda **kw: fuzz_jld2(capsys, shared, **kw), S_JLD2),
        (lambda **kw: fuzz_mesh(capsys, shared, **kw), S_MESH),
        (lambda **kw: fuzz_voxels(capsys, **kw), S_VOXELS),
        (lambda **kw: fuzz_toml(capsys=capsys, **kw), S_TOML),
        (lambda **kw: fuzz_csv(box_scene, **kw), S_CSV),
        (lambda **kw: fuzz_simulate(capsys, **kw), S_SIM),
        (lambda **kw: fuzz_bench(capsys, **kw), S_BENCH),
    ]:
        SLOW(given(**strategies)(test))()
    total = sum(COUNTS.values())
    with capsys.disabled():
        print(f"\nfuzz: {total} inputs, " + ", ".join(f"{v} {a} {r}" for (v, r), a in
                                                    ((k, n) for k, n in sorted(COUNTS.items()))))
    assert total >= 300
