"""Benchmarks behind ``dano bench``: wall times as JSON (medians of repeats; the first,
compiling run reported separately). Machines are noisy: compare ratios measured in one run."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import json
import os
import platform
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Annotated, Callable

import jax
import jax.numpy as jnp
import numpy as np
import tyro

from . import sharding
from ._jax_setup import batched_compiler_options, enable_float64
from ._version import __version__
from .errors import DanoError
from .asset import build
from .contact import CONTACT_MODELS
from .experiments.energy import energy_check
from .experiments.mujoco_c import mujoco_c_slides
from .experiments.nerf_loop import ground_truth_loop
from .experiments.push import PushPandaConfig, PushSphereConfig, push_panda_task, push_sphere_task, solve_task
from .experiments.real2sim import synthetic_slide_real2sim
from .experiments.sysid_examples import (PUSH_TRUTH, analytic_slides, contactnets_identify, contactnets_problem,
                                         push_problem, soap_problem)
from .experiments.tracking_curves import tracking_colour, tracking_success_curve
from .fields import BoxField, SphereField, mesh_field
from .nerf import TrainConfig, load_dataset, train
from .sim import DanoObject, NewtonConfig, SimParams, State, compose, rollout_arrays, scan_steps
from .sim.dynamics import as_data
from .sim.implicit import iteration_limit, resolve_linear_solver
from .sim.scene import cast_floats
from .sim.scenes import PAPER_DROP_QUAT, load_scene
from .sysid import FitParameter, SysIdProblem, Weights, identify
from .sysid.solve import solve_least_squares
from .sysid.uncertainty import least_squares_functions
from .trajopt.ilqr import Multipliers, _compiled


def _time(fn: Callable[[], object], repeats: int) -> dict:
    t0 = time.perf_counter()
    fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return {"first_s": first, "median_s": statistics.median(times), "min_s": min(times), "repeats": repeats}


def _time_interleaved(fns: dict[str, Callable[[], object]], repeats: int) -> tuple[dict, dict]:
    """Time several functions in turn, round after round (each first called once to compile),
    so that a change in the machine's load falls on all of them alike. Returns ({name:
    :func:`_time`-style dict}, {name: list of the rounds' times [s]})."""
    firsts = {}
    for name, fn in fns.items():
        t0 = time.perf_counter()
        fn()
        firsts[name] = time.perf_counter() - t0
    rounds: dict[str, list] = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            t0 = time.perf_counter()
            fn()
            rounds[name].append(time.perf_counter() - t0)
    stats = {name: {"first_s": firsts[name], "median_s": statistics.median(t), "min_s": min(t), "repeats": repeats}
             for name, t in rounds.items()}
    return stats, rounds


def bench_build(repeats: int = 3, mesh_path=None) -> dict:
    """Time to build a 5000-sample asset from an analytic sphere and from a mesh field.

    mesh_path: a watertight mesh (default: a trimesh icosphere, subdivision 4, so the
    benchmark needs no outside file). Reports the signed-distance grid and the asset
    build (mass properties + samples + visual mesh) separately.
    """
    import trimesh

    results = {}
    sphere = SphereField(0.5)
    results["build_analytic_sphere_5000"] = _time(lambda: build(sphere, num_samples=5000), repeats)
    mesh = trimesh.load(mesh_path, force="mesh") if mesh_path else trimesh.creation.icosphere(4, radius=0.5)
    results["mesh_field_sdf_96"] = _time(lambda: mesh_field(mesh), repeats)
    field = mesh_field(mesh)
    results["build_mesh_field_5000"] = _time(lambda: build(field, num_samples=5000), repeats)
    results["mesh"] = str(mesh_path) if mesh_path else "icosphere(subdivisions=4)"
    return results


def _steps_per_second(fn, steps: int, repeats: int) -> dict:
    """Time ``fn()`` (a jitted rollout of ``steps`` steps; blocks until done)."""
    r = _time(lambda: jax.block_until_ready(fn()), repeats)
    r["steps"] = steps
    r["steps_per_s"] = steps / r["median_s"]
    r["us_per_step"] = 1e6 * r["median_s"] / steps
    r["compile_s"] = max(r["first_s"] - r["median_s"], 0.0)
    return r


def _hull_model(sc):
    """A MuJoCo model of ``sc``'s first DANO (the bunny-drop's bunny) as the convex hull of its
    samples on a plane, same mass, inertia, friction and time step: what a user would
    otherwise simulate. Returns (MjModel, hull vertex count)."""
    import mujoco
    import trimesh

    bunny = sc.assets[0]
    hull = trimesh.convex.convex_hull(bunny.points)
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_PLANE, size=[0, 0, 0.05])
    spec.add_mesh(name="hull", uservert=hull.vertices.ravel().tolist(), userface=hull.faces.ravel().tolist())
    body = spec.worldbody.add_body(name="bunny")
    body.add_freejoint()
    J = bunny.inertia
    body.mass, body.ipos, body.explicitinertial = bunny.mass, [0, 0, 0], True
    body.fullinertia = [J[0, 0], J[1, 1], J[2, 2], J[0, 1], J[0, 2], J[1, 2]]
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_MESH, meshname="hull", density=0, friction=[0.1, 0.005, 0.0001])
    spec.option.timestep = sc.dt
    return spec.compile(), len(hull.vertices)


#: three MuJoCo primitives out of the bunny drop's reach (it lands near x = 2.3, y = 1.8 [m])
UNTOUCHED_PRIMITIVES = """<mujoco><worldbody>
  <geom name="ground" type="plane" size="0 0 1"/>
  <geom name="wall" type="box" size="0.05 1 0.5" pos="-3 0 0.5"/>
  <geom name="post" type="capsule" size="0.05 0.5" pos="-2 -3 0.5"/>
  <geom name="ball" type="sphere" size="0.2" pos="0 -3 0.2"/>
</worldbody></mujoco>"""


def _bunny_drop_beside_primitives(drop):
    """(scene, params) of the bunny drop (``drop``: :func:`~dano.sim.scenes.bunny_drop`'s
    setup, whose state it keeps) composed with :data:`UNTOUCHED_PRIMITIVES`, every pair with
    the drop's friction."""
    obj = DanoObject("bunny", drop.scene.assets[0], (0, 0, 1.1), PAPER_DROP_QUAT)
    scene = compose([obj], UNTOUCHED_PRIMITIVES, dt=drop.scene.dt)
    return scene, scene.default_params(sliding_friction=float(drop.params.contact.sliding_friction[0]))


def _two_meshes_apart():
    """{label: (scene, state, params)} of two 10 cm spheres made from a mesh (an icosphere's
    signed-distance grid: :func:`~dano.fields.mesh_field`, 2,000 samples each, 1 kg), dropped
    1 m apart and sliding away from each other, never touching: with every pair (their
    DANO-DANO pair skips both fields' queries while apart) and with their ground pairs only."""
    import trimesh

    from .fields import mesh_field
    from .sim.scenes import initial_state

    asset = build(mesh_field(trimesh.creation.icosphere(subdivisions=3, radius=0.1), resolution=32), mass=1.0,
                  num_samples=2000, mesh_resolution=0, name="sphere")
    objs = [DanoObject("a", asset, (0, 0, 0.5)), DanoObject("b", asset, (1.0, 0, 0.5))]
    out = {}
    for label, contacts in (("two_meshes_apart", None), ("two_meshes_ground_pairs_only", [("a", "ground"),
                                                                                           ("b", "ground")])):
        scene = compose(objs, dt=0.01, contacts=contacts)
        state = initial_state(scene, {"a": ((0, 0, 0.5), (1, 0, 0, 0)), "b": ((1.0, 0, 0.5), (1, 0, 0, 0))},
                              {"a": ((-0.3, 0, 0), (0, 0, 0)), "b": ((0.3, 0, 0), (0, 0, 0))})
        out[label] = (scene, state, scene.default_params())
    return out


def _slides_on_a_face() -> dict:
    """{label: (scene, state, params)} of objects sliding on a face, by each contact model:
    the paper bunny upright (``bunny-slide``: 111 samples within reach at rest), and a
    10 × 6 × 3 cm, 0.3 kg box (:class:`~dano.fields.BoxField`, 5000 samples: its largest
    face 1,462) pushed at 1 m/s on its largest face, per sample with the room
    :meth:`~dano.contact.per_sample.PerSample.sized_for` gives it and with the default 64
    of a round object (the all-samples fallback in every step)."""
    from .contact.per_sample import DEFAULT_MAX_ACTIVE, PerSample
    from .sim.scenes import initial_state

    out = {}
    for label, model in (("bunny_slide", "centroid"), ("bunny_slide_per_sample", "per_sample")):
        slide = load_scene("bunny-slide", contact_model=model)
        out[label] = (slide.scene, slide.state0, slide.params)
    box = build(BoxField((0.05, 0.03, 0.015)), mass=0.3, num_samples=5000, seed=0, mesh_resolution=0, name="box")
    for label, model in (("box_slide", "centroid"), ("box_slide_per_sample", "per_sample"),
                         ("box_slide_per_sample_64", PerSample(max_active=DEFAULT_MAX_ACTIVE))):
        scene = compose([DanoObject("box", box, (0, 0, 0.015))], dt=0.01, contact_model=model)
        state = initial_state(scene, {"box": ((0, 0, 0.015), (1, 0, 0, 0))}, {"box": ((1.0, 0.2, 0), (0, 0, 2.0))})
        out[label] = (scene, state, scene.default_params(sliding_friction=0.3))
    return out


def bench_sim(repeats: int = 5, steps: int = 10000, mujoco_steps: int = 100000) -> dict:
    """Simulation speed (CPU or GPU, float64), all measured in this one run (the default
    step counts keep every timing above 0.2 s on the 2-core CPU):

    * ``bunny_drop``: the paper bunny (5000 samples) on the ground, ``steps`` steps inside
      one jitted ``lax.scan``, centroid contact model; steps/s and compile time;
      ``bunny_drop_per_sample`` the same with the per-sample model
      (``ratio_per_sample_over_centroid_time``); ``bunny_drop_float32`` the centroid model
      in float32; ``bunny_drop_lapack`` the centroid model with its Newton systems solved by
      LAPACK (``NewtonConfig(linear_solver="lapack")``: the rollout is then not compiled
      into one kernel; ``ratio_lapack_over_default_time``);
    * ``mujoco_c_convex_hull``: what a user would otherwise pick: MuJoCo C (``mujoco.rollout``,
      no Python loop) simulating the same bunny as a convex-hull mesh collider from the same
      state; ``ratio_dano_over_mujoco_c`` compares steps/s;
    * ``bunny_drop_untouched_primitives``: the same drop composed with a box, a capsule and a
      sphere it never reaches (:data:`UNTOUCHED_PRIMITIVES`; a user's walls and posts), whose
      pairs skip their samples (``ratio_untouched_primitives_over_drop_time``);
    * ``two_meshes_apart``: two mesh-made DANOs that never touch, with their DANO-DANO pair
      (which skips both fields' queries while apart), and ``two_meshes_ground_pairs_only``
      the same without it (``ratio_dano_pair_apart_over_ground_pairs_only_time``: 10.2 before
      the skip over 10,000 steps, 2.1 after, 2026-11-29);
    * objects sliding on a face (:func:`_slides_on_a_face`): ``bunny_slide`` and
      ``bunny_slide_per_sample`` (``ratio_per_sample_over_centroid_time_slide``), ``box_slide``,
      ``box_slide_per_sample`` (``ratio_per_sample_over_centroid_time_box``) and
      ``box_slide_per_sample_64``, the box with the default room of a round object
      (``ratio_box_per_sample_64_over_sized_time``: what sizing the gathering for the face saves);
    * these thirteen are timed round after round (``repeats`` rounds, each round one run of each),
      so that a change in the machine's load falls on all alike; the two ratios are medians
      over the rounds of the ratio within each round;
    * ``sphere_hits_bunny``: the scene of that name (a 10 kg ball rolls into the bunny): a
      DANO against a MuJoCo primitive geom (:mod:`dano.contact.primitive`) besides the
      ground, ``steps`` steps as ``bunny_drop``, timed on its own after the four above
      (``ratio_sphere_hits_over_drop_time``: its time over ``bunny_drop``'s median);
    * ``panda_push_bunny``: the Panda + bunny scene (needs ``$MENAGERIE_ROOT``); a collapse
      of its steps/s would show the CPU fusion-emitter slowdown coming back;
    * ``jacfwd_200``: forward-mode Jacobian of a 200-step bunny rollout w.r.t. 2 parameters
      (sliding friction, mass scale α).
    """
    import mujoco
    import mujoco.rollout

    out: dict = {}
    setup = load_scene("bunny-drop")
    sc, s0, p = setup.scene, setup.state0, setup.params
    ps = load_scene("bunny-drop", contact_model="per_sample")
    sc32, p32, s32 = (cast_floats(x, jnp.float32) for x in (sc, p, s0))

    # MuJoCo C with the bunny as a convex hull of its samples
    m, hull_vertices = _hull_model(sc)
    d = mujoco.MjData(m)
    d.qpos[:], d.qvel[:] = np.asarray(s0.qpos), np.asarray(s0.qvel)
    state0 = np.empty(mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS))
    mujoco.mj_getState(m, d, state0, mujoco.mjtState.mjSTATE_FULLPHYSICS)

    # the same drop beside a box, a capsule and a sphere it never reaches (a user's scene:
    # walls, posts): their pairs skip their samples (dano.contact.base.skip_separated)
    far, far_params = _bunny_drop_beside_primitives(setup)
    # the same drop with the Newton systems solved by LAPACK: what the step costs when XLA
    # cannot compile the rollout into one kernel (NewtonConfig.linear_solver)
    lapack = NewtonConfig(linear_solver="lapack")
    pair = _two_meshes_apart()
    faces = _slides_on_a_face()
    # timed round after round, so that the machine's load falls on all of them alike
    stats, rounds = _time_interleaved({
        "bunny_drop": lambda: jax.block_until_ready(rollout_arrays(sc, s0, None, p, steps)),
        "bunny_drop_per_sample": lambda: jax.block_until_ready(rollout_arrays(ps.scene, s0, None, ps.params, steps)),
        "bunny_drop_float32": lambda: jax.block_until_ready(rollout_arrays(sc32, s32, None, p32, steps)),
        "bunny_drop_lapack": lambda: jax.block_until_ready(rollout_arrays(sc, s0, None, p, steps, newton=lapack)),
        "bunny_drop_untouched_primitives": lambda: jax.block_until_ready(
            rollout_arrays(far, s0, None, far_params, steps)),
        "mujoco_c_convex_hull": lambda: mujoco.rollout.rollout(m, d, state0[None], nstep=mujoco_steps),
        **{label: (lambda a=args: jax.block_until_ready(rollout_arrays(a[0], a[1], None, a[2], steps)))
           for label, args in {**pair, **faces}.items()},
    }, repeats)
    for name, r in stats.items():
        n = mujoco_steps if name == "mujoco_c_convex_hull" else steps
        r.update(steps=n, steps_per_s=n / r["median_s"], us_per_step=1e6 * r["median_s"] / n)
        if name != "mujoco_c_convex_hull":
            r["compile_s"] = max(r["first_s"] - r["median_s"], 0.0)
        out[name] = r
    out["bunny_drop"].update(num_samples=sc.assets[0].num_samples, contact_model="centroid")
    out["bunny_drop_per_sample"]["contact_model"] = "per_sample"
    out["mujoco_c_convex_hull"]["hull_vertices"] = hull_vertices
    c_step = [t / mujoco_steps for t in rounds["mujoco_c_convex_hull"]]
    # ratios: medians over the rounds of the ratio within each round
    out["ratio_per_sample_over_centroid_time"] = statistics.median(
        a / b for a, b in zip(rounds["bunny_drop_per_sample"], rounds["bunny_drop"]))
    out["ratio_dano_over_mujoco_c"] = statistics.median(
        c / (t / steps) for c, t in zip(c_step, rounds["bunny_drop"]))
    out["bunny_drop"]["linear_solver"] = resolve_linear_solver(NewtonConfig(), sc, steps).linear_solver
    out["bunny_drop_lapack"]["linear_solver"] = "lapack"
    out["ratio_lapack_over_default_time"] = statistics.median(
        a / b for a, b in zip(rounds["bunny_drop_lapack"], rounds["bunny_drop"]))

    out["ratio_untouched_primitives_over_drop_time"] = statistics.median(
        a / b for a, b in zip(rounds["bunny_drop_untouched_primitives"], rounds["bunny_drop"]))
    out["ratio_dano_pair_apart_over_ground_pairs_only_time"] = statistics.median(
        a / b for a, b in zip(rounds["two_meshes_apart"], rounds["two_meshes_ground_pairs_only"]))
    for ratio, (a, b) in {"ratio_per_sample_over_centroid_time_slide": ("bunny_slide_per_sample", "bunny_slide"),
                          "ratio_per_sample_over_centroid_time_box": ("box_slide_per_sample", "box_slide"),
                          "ratio_box_per_sample_64_over_sized_time": ("box_slide_per_sample_64",
                                                                      "box_slide_per_sample")}.items():
        out[ratio] = statistics.median(x / y for x, y in zip(rounds[a], rounds[b]))
    for label in ("bunny_slide_per_sample", "box_slide_per_sample", "box_slide_per_sample_64"):
        out[label]["max_active"] = faces[label][0].info.pairs[0].model.capacity[0]

    hits = load_scene("sphere-hits-bunny")
    out["sphere_hits_bunny"] = _steps_per_second(
        lambda: rollout_arrays(hits.scene, hits.state0, None, hits.params, steps), steps, repeats)
    out["ratio_sphere_hits_over_drop_time"] = out["sphere_hits_bunny"]["median_s"] / out["bunny_drop"]["median_s"]

    if os.environ.get("MENAGERIE_ROOT"):
        ps = load_scene("panda-push-bunny")
        n = 1000
        ctrl = jnp.asarray(ps.controls(np.arange(n) * ps.scene.dt))
        out["panda_push_bunny"] = _steps_per_second(
            lambda: rollout_arrays(ps.scene, ps.state0, ctrl, ps.params, n), n, repeats)
    else:
        out["panda_push_bunny"] = "skipped: set MENAGERIE_ROOT to the Menagerie folder"

    def final_state(theta):
        params = SimParams(dataclasses.replace(p.contact, sliding_friction=theta[:1]), theta[1:2])
        qpos, qvel, _ = rollout_arrays(sc, State(s0.qpos, s0.qvel), None, params, 200)
        return jnp.concatenate([qpos[-1], qvel[-1]])

    jac = jax.jit(jax.jacfwd(final_state))
    theta = jnp.asarray([0.1, float(p.alpha[0])])
    out["jacfwd_200"] = _time(lambda: jax.block_until_ready(jac(theta)), repeats)
    out["jacfwd_200"]["parameters"] = ["sliding_friction", "alpha"]
    return out


def bench_sysid(repeats: int = 3, cube_data: str | None = None, cube_tosses: int = 10) -> dict:
    """Identification wall times (solver only; compilation reported separately), with AD
    Jacobians and, in the same run, with SciPy's finite-difference Jacobians:

    * ``soap``: the real soap video (sliding friction + 2 nuisance velocities), median of
      ``repeats`` solves;
    * ``bunny_pushes``: α and friction from 10 noisy pushes (one solve each way; the slow one);
    * ``compile_by_lengths``: compile time for 20 trajectories of 20 lengths vs one length;
    * ``jacobian_by_segments``: one residual and Jacobian of 16 and 64 slides with fitted start
      velocities (n = 97 and 385);
    * ``local_solve_by_segments``: 30 evaluations of the local solver on those 64 slides, on the
      whole residual and compressed segment by segment, side by side;
    * ``batch_by_segments``: the residuals at 32 parameter vectors (the profiles' and scans'
      batched evaluation) of 1, 4, 16 and 64 slides, as dano runs them and as one vmap, alternately;
    * ``contactnets_cube`` (with ``cube_data``, the ContactNets .npz): the whole example's wall
      and compile time on ``cube_tosses`` tosses, and its local solve with AD vs FD Jacobians.
    """
    out: dict = {}
    problem = soap_problem(substeps=4)
    for jac in ("ad", "fd"):
        runs = [identify(problem, jacobian=jac) for _ in range(repeats + 1)]
        walls = [r.wall_time_s for r in runs[1:]]
        out[f"soap_{jac}"] = {"median_s": statistics.median(walls), "first_compile_s": runs[0].compile_time_s,
                              "sliding_friction": float(runs[-1].estimates[0]), "nfev": runs[-1].nfev,
                              "njev": runs[-1].njev}
    out["soap_ratio_fd_over_ad"] = out["soap_fd"]["median_s"] / out["soap_ad"]["median_s"]
    problem = push_problem(1e-3, 0.5)
    for jac in ("ad", "fd"):
        r = identify(problem, jacobian=jac, horizons=(0.4,), scan=0)  # the example's configuration
        est = dict(zip(r.labels, r.estimates))
        out[f"bunny_pushes_{jac}"] = {
            "wall_s": r.wall_time_s, "compile_s": r.compile_time_s, "nfev": r.nfev, "njev": r.njev,
            "alpha_rel_error": est["bunny:alpha"] / PUSH_TRUTH["alpha"] - 1,
            "friction_rel_error": est["bunny/ground:sliding_friction"] / PUSH_TRUTH["sliding_friction"] - 1}
    out["bunny_pushes_ratio_fd_over_ad"] = out["bunny_pushes_fd"]["wall_s"] / out["bunny_pushes_ad"]["wall_s"]
    out["compile_by_lengths"] = _compile_by_lengths()
    out["jacobian_by_segments"] = _jacobian_by_segments()
    out["local_solve_by_segments"] = _local_solve_by_segments()
    out["batch_by_segments"] = _batch_by_segments()
    out["soap_command"] = command_times(["sysid", "soap", "--json", "--out-dir", "{out}"],
                                        repeats=max(repeats - 1, 1))
    if cube_data:
        report = contactnets_identify(cube_data, cube_tosses)[2]
        out["contactnets_cube"] = {k: report[k] for k in (
            "num_tosses", "sliding_friction", "cost", "wall_time_s", "compile_time_s", "heldout_position_rms_mm")}
        problem = contactnets_problem(cube_data, cube_tosses)[0]
        for jac in ("ad", "fd"):  # the local solve alone, from the same start, each way
            r = identify(problem, jacobian=jac)
            out[f"contactnets_cube_{jac}"] = {"wall_s": r.wall_time_s, "compile_s": r.compile_time_s,
                                              "nfev": r.nfev, "njev": r.njev, "cost": r.final_cost,
                                              "sliding_friction": float(r.estimates[0])}
        out["contactnets_cube_ratio_fd_over_ad"] = (out["contactnets_cube_fd"]["wall_s"]
                                                    / out["contactnets_cube_ad"]["wall_s"])
    else:
        out["contactnets_cube"] = "skipped: give --cube-data (the ContactNets tosses .npz)"
    return out


def _timed_command(args: list[str], cache: str, out: str) -> float:
    """Seconds of ``dano ARGS`` in a fresh process with compilation cache ``cache``; ``{out}``
    in an argument becomes ``out``."""
    env = {**os.environ, "DANO_CACHE_DIR": cache}
    t0 = time.perf_counter()
    subprocess.run([sys.executable, "-m", "dano.cli", *(a.replace("{out}", out) for a in args)], env=env, check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t0


def command_times(args: list[str], repeats: int = 2) -> dict:
    """Wall time of ``dano ARGS`` as a user runs it (a fresh process, start-up and writing
    included): once with an empty compilation cache (cold), then ``repeats`` times with the cache
    that run filled (warm; median). ``{out}`` in an argument becomes a fresh folder in a
    temporary directory for each run. Returns {"command", "cold_s", "warm_s", "warm_runs"}."""
    with tempfile.TemporaryDirectory() as tmp:
        cold = _timed_command(args, os.path.join(tmp, "cache"), os.path.join(tmp, "out0"))
        warm = [_timed_command(args, os.path.join(tmp, "cache"), os.path.join(tmp, f"out{k + 1}"))
                for k in range(repeats)]
    return {"command": "dano " + " ".join(args), "cold_s": cold, "warm_s": statistics.median(warm), "warm_runs": warm}


def new_problem_times(first: list[str], then: list[str]) -> dict:
    """Time to first result of a new problem of a structure already compiled (issue 32: 'every
    new object or problem pays this again'): ``dano FIRST`` once with an empty compilation
    cache, then ``dano THEN`` (e.g. the same identification for another object) once with the
    cache the first filled, each a fresh process. Returns {"first_command", "first_cold_s",
    "command", "new_problem_s"}."""
    with tempfile.TemporaryDirectory() as tmp:
        cache = os.path.join(tmp, "cache")
        first_s = _timed_command(first, cache, os.path.join(tmp, "out0"))
        then_s = _timed_command(then, cache, os.path.join(tmp, "out1"))
    return {"first_command": "dano " + " ".join(first), "first_cold_s": first_s, "command": "dano " + " ".join(then),
            "new_problem_s": then_s}


def bench_latency(repeats: int = 2) -> dict:
    """Time to first result of the commands users wait for (:func:`command_times`: a fresh
    process each, cold = an empty compilation cache, warm = the cache that run filled; medians of
    ``repeats`` warm runs): ``dano sysid soap``, a user's TOML identification (three MuJoCo C
    slides of the low-poly bunny as a 0.2 m, 0.7 kg toy; needs the shared data's mesh, else
    skipped), ``dano trajopt push-sphere``, ``dano simulate bunny-drop --duration 2`` and
    ``dano demo``; with the shared data's meshes, a new object's first run with the cache a
    first object filled (:func:`new_problem_times`): Spot's identification after the bunny's
    (``sysid_new_object_toml``), the bunny's with a fourth slide after its three
    (``sysid_more_slides_toml``) and its simulation in a user's scene after the bunny's
    (``simulate_new_object``); and the bunny drop for 3 s after the one for 2 s
    (``simulate_new_duration``)."""
    repeats = max(1, repeats)
    out: dict = {
        "sysid_soap": command_times(["sysid", "soap", "--json", "-o", "{out}"], repeats),
        "trajopt_push_sphere": command_times(["trajopt", "push-sphere", "--json", "--quiet", "--no-video", "-o",
                                              "{out}"], repeats),
        "simulate_bunny_drop_2s": command_times(["simulate", "bunny-drop", "--duration", "2", "--out",
                                                 "{out}/drop.npz"], repeats),
        "demo": command_times(["demo", "--out-dir", "{out}"], repeats),
        # another duration of the same scene: the rollout's step count is an argument, not a shape
        "simulate_new_duration": new_problem_times(["simulate", "bunny-drop", "--duration", "2", "--out",
                                                    "{out}/drop.npz"],
                                                   ["simulate", "bunny-drop", "--duration", "3", "--out",
                                                    "{out}/drop.npz"]),
    }
    data_dir = _shared_data()
    meshes = None if data_dir is None else data_dir / "meshes"
    if meshes is None or not (meshes / "bunny_lowpoly.obj").is_file() or not (meshes / "spot.obj").is_file():
        out["sysid_own_toml"] = "skipped: needs meshes/bunny_lowpoly.obj and spot.obj of the shared data " \
                                "($DANO_SHARED_DATA)"
        return out
    with tempfile.TemporaryDirectory() as tmp:
        made = mujoco_c_slides(Path(tmp) / "toy", mesh=str(meshes / "bunny_lowpoly.obj"))
        out["sysid_own_toml"] = command_times(["sysid", str(made["toml"]), "--json", "-o", "{out}"], repeats)
        out["sysid_own_toml"]["problem"] = "3 MuJoCo C slides of bunny_lowpoly.obj at 0.2 m, 0.7 kg (friction 0.5)"
        # the same object with a fourth slide: segment counts are padded to buckets (3 and 4 run as 4)
        more = mujoco_c_slides(Path(tmp) / "more", mesh=str(meshes / "bunny_lowpoly.obj"), slides=4, seed=2)
        out["sysid_more_slides_toml"] = new_problem_times(["sysid", str(made["toml"]), "--json", "-o", "{out}"],
                                                          ["sysid", str(more["toml"]), "--json", "-o", "{out}"])
        out["sysid_more_slides_toml"]["problem"] = "4 MuJoCo C slides of the same toy after its 3"
        # a second object of its own: Spot, the same kind of problem (other mesh, size, mass, friction)
        spot = mujoco_c_slides(Path(tmp) / "spot", mesh=str(meshes / "spot.obj"), friction=0.3, seed=1)
        out["sysid_new_object_toml"] = new_problem_times(["sysid", str(made["toml"]), "--json", "-o", "{out}"],
                                                         ["sysid", str(spot["toml"]), "--json", "-o", "{out}"])
        out["sysid_new_object_toml"]["problem"] = "3 MuJoCo C slides of spot.obj at 0.2 m, 0.7 kg (friction 0.3), " \
                                                  "after the bunny's"
        scene = Path(tmp) / "scene.xml"
        scene.write_text('<mujoco><option timestep="0.01"/><worldbody><geom name="floor" type="plane" '
                         'size="5 5 0.1"/></worldbody></mujoco>')

        def simulate(obj) -> list[str]:
            return ["simulate", str(scene), "--object", f"{obj}@0,0,0.15", "--duration", "1", "--out", "{out}/run.npz"]

        out["simulate_new_object"] = new_problem_times(simulate(made["dano"]), simulate(spot["dano"]))
    return out


def _box_slides_scene(dt: float):
    """The analytic slides' box (0.1 × 0.1 × 0.05 m, 1 kg, 400 samples) on the ground, time step ``dt``."""
    asset = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=16,
                  name="box")
    return compose([DanoObject("box", asset, (0, 0, 0.05))], dt=dt)


def _jacobian_by_segments(counts: tuple[int, ...] = (16, 64), repeats: int = 5) -> dict:
    """One residual and Jacobian of box slides (20 frames, 2 substeps) with each slide's start
    velocity fitted (6 nuisance entries a slide: n = 1 + 6 × slides), per slide count: the
    first call (trace, compile, run) and the median of ``repeats`` more. Forward mode carries
    θ's global entries and one offset per batch, not all n (docs/sysid.md, "Jacobians")."""
    out: dict = {}
    for count in counts:
        problem = _slides_with_start_velocities(count)
        theta = problem.initial() + 0.001
        r = _time(lambda: problem.residuals_and_jacobian(theta), repeats)
        out[f"slides_{count}"] = {"n": problem.num_parameters, "m": problem.num_residuals, **r}
    return out


def _slides_with_start_velocities(count: int) -> SysIdProblem:
    """Box slides (20 frames, 2 substeps, 1 mm noise) with each slide's start velocity fitted
    (6 nuisance entries a slide: n = 1 + 6 × ``count``)."""
    enable_float64()
    return SysIdProblem(_box_slides_scene(0.005), analytic_slides(0, 0.05, count, frames=20, noise=0.001),
                        [FitParameter("sliding_friction", 0.3, 0.0, 2.0)], weights=Weights((1.0, 1.0, 1.0), 1.0),
                        substeps=2, fit_velocity="xyz", fit_angular_velocity="xyz")


def _local_solve_by_segments(count: int = 64, evaluations: int = 30) -> dict:
    """The local solver (:func:`~dano.sysid.solve.solve_least_squares`, ``evaluations``
    residual evaluations from the initial guess) on ``count`` box slides with fitted start
    velocities, on the residual as it is and compressed segment by segment
    (:meth:`~dano.sysid.problem.JacobianBlocks.compressed`), side by side after one
    compiling call: wall times, costs and how far the estimates are apart."""
    problem = _slides_with_start_velocities(count)
    x0, (lo, hi) = problem.initial(), problem.bounds()
    problem.residuals_and_jacobian(x0)
    out: dict = {"n": problem.num_parameters, "m": problem.num_residuals, "evaluations": evaluations}
    fits = {}
    for key, compress in (("whole", False), ("compressed", True)):
        f = least_squares_functions(problem, compress=compress)
        fits[key] = fit = solve_least_squares(f.fun, x0, lo, hi, jacobian=f.jac, max_iterations=evaluations)
        out[key] = {"wall_s": fit.wall_time_s, "cost": fit.cost, "nfev": fit.nfev,
                    "rows_seen": len(f.fun(fit.x))}
    out["ratio_whole_over_compressed"] = out["whole"]["wall_s"] / out["compressed"]["wall_s"]
    out["max_abs_estimate_difference"] = float(np.max(np.abs(fits["whole"].x - fits["compressed"].x)))
    return out


def _batch_by_segments(counts: tuple[int, ...] = (1, 4, 16, 64), vectors: int = 32, repeats: int = 3) -> dict:
    """:meth:`~dano.sysid.problem.SysIdProblem.batch_residuals` at ``vectors`` parameter vectors
    of box slides with fitted start velocities, per slide count: as dano runs it (on a CPU,
    :func:`~dano.sysid.problem.batch_chunk` vectors at a time) and with every batch one vmap,
    alternately after a compiling call of each: medians of ``repeats`` [s], their ratio and
    the largest difference of the residuals."""
    from .sysid import problem as sysid_problem

    out: dict = {}
    for count in counts:
        problem = _slides_with_start_velocities(count)
        rng = np.random.default_rng(0)
        thetas = problem.initial() + rng.normal(0.0, 0.01, (vectors, problem.num_parameters))
        thetas[:, 0] = np.linspace(0.1, 0.9, vectors)
        runs: dict = {"chunked": [], "vmap": []}
        results = {}
        default = sysid_problem.CPU_ROLLOUTS_PER_CHUNK
        try:
            for k in range(repeats + 1):
                for key, per_chunk in (("chunked", default), ("vmap", 10**9)):
                    sysid_problem.CPU_ROLLOUTS_PER_CHUNK = per_chunk
                    t0 = time.perf_counter()
                    results[key] = problem.batch_residuals(thetas)
                    if k:
                        runs[key].append(time.perf_counter() - t0)
        finally:
            sysid_problem.CPU_ROLLOUTS_PER_CHUNK = default
        chunk = sysid_problem.batch_chunk(problem.layout, sysid_problem.BATCH)
        out[f"slides_{count}"] = {
            "n": problem.num_parameters, "vectors_per_chunk": chunk,
            "chunked_median_s": statistics.median(runs["chunked"]), "vmap_median_s": statistics.median(runs["vmap"]),
            "ratio_vmap_over_chunked": statistics.median(runs["vmap"]) / statistics.median(runs["chunked"]),
            "max_abs_difference": float(np.max(np.abs(results["chunked"] - results["vmap"])))}
    return out


def _compile_by_lengths(count: int = 20) -> dict:
    """Compile time of an identification's residual and Jacobian for ``count`` trajectories of
    ``count`` different lengths (11, 12, … frames) against one trajectory of the longest
    length: the lengths are padded into one batch, so the first should not cost much more."""
    enable_float64()
    scene = _box_slides_scene(0.0025)
    longest = 10 + count
    slides = analytic_slides(0, 0.05, count, frames=longest)
    out: dict = {"trajectories": count, "frames": [11, longest]}
    for key, obs in (("one_length_s", slides[:1]), ("distinct_lengths_s", [
            dataclasses.replace(o, time=o.time[: 11 + k], poses={"box": o.poses["box"][: 11 + k]})
            for k, o in enumerate(slides)])):
        problem = SysIdProblem(scene, obs, [FitParameter("sliding_friction", 0.3, 0.0, 2.0)],
                               weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4)
        t0 = time.perf_counter()
        theta = problem.initial()
        problem.residuals(theta), problem.jacobian(theta)  # compiled on first use (NumPy results: done)
        out[key] = time.perf_counter() - t0
    out["ratio"] = out["distinct_lengths_s"] / out["one_length_s"]
    return out


def _drops(b: int, sc, s0):
    """B bunny-drop initial states (qpos (B, nq), qvel (B, nv)): the drop's, velocities perturbed (seeded by B)."""
    rng = np.random.default_rng(b)
    return jnp.tile(s0.qpos, (b, 1)), jnp.asarray(np.asarray(s0.qvel) + rng.normal(0, 0.2, (b, sc.nv)))


def bench_batched(repeats: int = 3, steps: int = 200, batches: tuple[int, ...] | None = None) -> dict:
    """Batched throughput: ``jax.vmap`` of the bunny-drop rollout over B initial states
    (perturbed drop velocities), as env-steps per second, the batch split over the devices
    in use (:mod:`dano.sharding`, ``--devices``; one device: ``jax.jit(jax.vmap(...))``).
    Default B: 1, 16, 64 on CPU and 1, 1024, 4096 on a GPU."""
    setup = load_scene("bunny-drop")
    sc, s0, p = setup.scene, setup.state0, setup.params
    if batches is None:
        batches = (1, 1024, 4096) if jax.default_backend() == "gpu" else (1, 16, 64)
    out: dict = {"steps": steps, "backend": jax.default_backend(), "devices": sharding.devices_in_use()}
    run = sharding.sharded_vmap(lambda q, v: rollout_arrays(sc, State(q, v), None, p, steps)[0][-1])
    for b in batches:
        qpos, qvel = _drops(b, sc, s0)
        r = _time(lambda: jax.block_until_ready(run(qpos, qvel)), repeats)
        r["env_steps_per_s"] = b * steps / r["median_s"]
        out[f"batch_{b}"] = r
    return out


#: batch sizes of the scaling suite: on a GPU up to 262,144 drops, on a CPU a few small ones
SCALING_BATCHES = {"gpu": (1024, 4096, 16384, 32768, 65536, 131072, 262144), "cpu": (16, 64, 256)}


def scaling_point(engine: str, dtype: str, batch: int, steps: int = 200, repeats: int = 2,
                  linear_solver: str = "auto", compiler_options: dict | None = None) -> dict:
    """One point of the scaling suite, in this process: ``batch`` bunny drops of ``steps``
    steps (the batched suite's initial states, seeded by ``batch``) vmapped in one jitted
    program on the default device, in ``dtype`` (float32 or float64): ``engine`` "dano" (the
    paper bunny, 5000 samples, centroid contact model) or "mjx" (plain MJX, the same bunny as
    the convex hull of its samples, :func:`_hull_model`). Returns :func:`_time`'s dict with
    env-steps/s and the device's peak memory (``peak_bytes``: XLA's allocator statistics where
    the device keeps them, else None; ``max_rss_bytes``: the process's peak resident memory);
    for dano also the Newton iterations (B, T) of the last timed run: ``iterations_mean`` per
    env-step, ``loop_trips`` (the sum over steps of the batch's largest count: what the
    vmapped Newton loop runs), ``typical_env_trips`` (the median env's sum), ``envs_at_max``
    (envs whose Newton solve used all its iterations in some step) and ``non_finite_envs``;
    ``linear_solver``: :attr:`~dano.sim.NewtonConfig.linear_solver` of dano's steps;
    ``compiler_options``: XLA options of the jitted rollout (``jax.jit(compiler_options=)``);
    None: dano's as it runs its batched rollouts (:func:`dano.sim.batched_compiler_options`: on an
    NVIDIA GPU, loops in CUDA graphs) and XLA's defaults for plain MJX (as MJX users run it).
    ``final_height_mean_m``: the envs' mean final height of the body [m] (a check that
    variants of one point simulate the same drops); ``dano_path``: the directory of the dano
    package that ran the point."""
    import resource

    if dtype == "float64" or engine == "dano":  # plain MJX in float32 runs as MJX users run it: 64-bit mode off
        enable_float64()
    dt = jnp.dtype(dtype)
    setup = load_scene("bunny-drop")
    sc, s0, p = setup.scene, setup.state0, setup.params
    qpos, qvel = (x.astype(dt) for x in _drops(batch, sc, s0))
    out: dict = {"engine": engine, "dtype": dtype, "batch": batch, "steps": steps, "backend": jax.default_backend(),
                 "dano_path": str(Path(__file__).parent)}
    if engine == "dano":
        scd, pd = sc.astype(dt), cast_floats(p, dt)
        newton = resolve_linear_solver(NewtonConfig(linear_solver=linear_solver), scd, steps)
        out["linear_solver"] = newton.linear_solver
        ctrl, f = jnp.zeros((steps, scd.nu), dt), jnp.zeros((steps, scd.nv), dt)

        def roll(q, v):
            _, qs, vs, _, iters = scan_steps(scd, pd, as_data(scd, State(q, v)), ctrl, f, newton, False)
            return qs[-1], vs[-1], iters

        options = batched_compiler_options() if compiler_options is None else compiler_options
        run = jax.jit(jax.vmap(roll), compiler_options=options)
    elif engine == "mjx":
        from ._mjx import mjx

        m, out["hull_vertices"] = _hull_model(sc)
        mx = cast_floats(mjx.put_model(m), dt)
        d0 = cast_floats(mjx.make_data(mx), dt)

        def roll(q, v):
            d = jax.lax.scan(lambda d, _: (mjx.step(mx, d), None), d0.replace(qpos=q, qvel=v), None, length=steps)[0]
            return d.qpos, d.qvel, jnp.zeros((steps,), dt)

        options = compiler_options or {}
        run = jax.jit(jax.vmap(roll), compiler_options=options)
    else:
        raise DanoError(f"unknown engine {engine!r}: dano or mjx")
    last: list = []  # the final states and iterations of the last timed run (not one run more)

    def call():
        last[:] = [jax.block_until_ready(run(qpos, qvel))]

    out["compiler_options"] = options
    r = _time(call, repeats)
    qf, vf, iters = (np.asarray(x) for x in last[0])
    r.update(out, env_steps_per_s=batch * steps / r["median_s"], compile_s=max(r["first_s"] - r["median_s"], 0.0))
    finite = np.isfinite(qf).all(1) & np.isfinite(vf).all(1)
    r["non_finite_envs"] = int((~finite).sum())
    r["final_height_mean_m"] = float(np.mean(qf[finite, 2])) if finite.any() else None
    if engine == "dano":
        r.update(iterations_mean=float(iters.mean()), loop_trips=int(iters.max(0).sum()),
                 typical_env_trips=float(np.median(iters.sum(1))),
                 envs_at_max=int((iters >= iteration_limit(scd, newton)).any(1).sum()))
    stats = jax.local_devices()[0].memory_stats() or {}
    r["peak_bytes"] = stats.get("peak_bytes_in_use")
    r["max_rss_bytes"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    return r


#: the process of :func:`scaling_point_in_process`: argv = (stacks file or "", seconds before
#: its stacks are dumped there, the point's keyword arguments as JSON); prints the result
_POINT_PROCESS = """
import faulthandler, json, sys
if sys.argv[1]:
    stacks = open(sys.argv[1], "a")
    faulthandler.dump_traceback_later(float(sys.argv[2]), exit=False, file=stacks)
import dano.bench as b
r = b.scaling_point(**json.loads(sys.argv[3]))
faulthandler.cancel_dump_traceback_later()
print("RESULT " + json.dumps(r), flush=True)
"""


def scaling_point_in_process(timeout_s: float, xla_flags: str = "", stacks: str | None = None, on_timeout=None,
                             env: dict | None = None, **kwargs) -> dict:
    """:func:`scaling_point` (its arguments ``kwargs``) in a fresh Python process, killed after
    ``timeout_s`` seconds (compile included) and then reported as ``{"timed_out_s":
    timeout_s}``; a process that ends without a result as ``{"error": its last lines of
    stderr}``; ``wall_s`` [s] added either way. ``xla_flags`` is appended to the process's
    XLA_FLAGS; ``stacks``: a file that the process's Python stacks are appended to 5 s before
    its limit where it is still running then (faulthandler); ``on_timeout()`` is called
    before a process past its limit is killed (e.g. to read the GPU's state); ``env``: further
    environment variables of the process (e.g. a PYTHONPATH that puts another checkout's
    ``src`` first, to time an earlier dano beside this one on the same machine; the result's
    ``dano_path`` says which ran)."""
    env = {**os.environ, **(env or {})}
    if xla_flags:
        env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + xla_flags).strip()
    t0 = time.perf_counter()
    proc = subprocess.Popen([sys.executable, "-c", _POINT_PROCESS, stacks or "", str(max(timeout_s - 5, 1)),
                             json.dumps(kwargs)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    try:
        stdout, stderr = proc.communicate(timeout=timeout_s)
        lines = [ln for ln in stdout.splitlines() if ln.startswith("RESULT ")]
        r = json.loads(lines[-1][7:]) if lines else {"error": stderr.strip().splitlines()[-5:]}
    except subprocess.TimeoutExpired:
        if on_timeout is not None:
            on_timeout()
        proc.kill()
        proc.communicate()
        r = {"timed_out_s": timeout_s}
    r["wall_s"] = time.perf_counter() - t0
    return r


def bench_scaling(repeats: int = 2, steps: int = 200, batches: tuple[int, ...] | None = None,
                  dtypes: tuple[str, ...] = ("float32", "float64"), engines: tuple[str, ...] = ("dano", "mjx"),
                  timeout_s: float = 300.0) -> dict:
    """Batched bunny drops at growing B, dano against plain MJX on the bunny's convex hull, in
    float32 and float64 (:func:`scaling_point`), each point in a fresh Python process on one
    device, so that a point that runs longer than ``timeout_s`` (seconds, compile included)
    is reported (``timed_out_s``) and the table goes on; each compiles afresh (no persistent
    compilation cache: a cached program would hide a compile that differs). Default B:
    :data:`SCALING_BATCHES` of the backend; a B given again is a further attempt, keyed
    ``{B}_2``, ``{B}_3``, ... Keys ``{engine}_{dtype}_{B}``; ratios
    ``ratio_dano_over_mjx_{dtype}_{B}`` of env-steps/s."""
    batches = batches or SCALING_BATCHES["gpu" if jax.default_backend() == "gpu" else "cpu"]
    out: dict = {"steps": steps, "batches": list(batches), "timeout_s": timeout_s}
    for i, b in enumerate(batches):
        # a B given again is a further attempt (a fresh process and compile): keys {B}_2, {B}_3, ...
        k = batches[:i].count(b)
        b_key = f"{b}_{k + 1}" if k else str(b)
        for dtype in dtypes:
            for engine in engines:
                r = scaling_point_in_process(timeout_s, engine=engine, dtype=dtype, batch=b, steps=steps,
                                             repeats=repeats)
                out[f"{engine}_{dtype}_{b_key}"] = r
                print(f"scaling {engine} {dtype} B={b}: " + (f"{r['env_steps_per_s']:.4g} env-steps/s"
                      if "env_steps_per_s" in r else str(r)), file=sys.stderr, flush=True)
            d, m = out.get(f"dano_{dtype}_{b_key}", {}), out.get(f"mjx_{dtype}_{b_key}", {})
            if "env_steps_per_s" in d and "env_steps_per_s" in m:
                out[f"ratio_dano_over_mjx_{dtype}_{b_key}"] = d["env_steps_per_s"] / m["env_steps_per_s"]
    return out


def _device_counts(available: int) -> list[int]:
    """1, 2, 4, … below ``available``, then ``available``."""
    counts, n = [], 1
    while n < available:
        counts.append(n)
        n *= 2
    return counts + [available]


def bench_sharded(repeats: int = 3, steps: int = 200, batch: int | None = None, trajectories: int = 8) -> dict:
    """Batches split over devices (:mod:`dano.sharding`), for 1, 2, 4, … devices up to those in
    use: ``rollouts``: B bunny drops (float64; default B = 64 on CPU, 4096 on a GPU) of
    ``steps`` steps, wall time and env-steps/s, and the largest difference of the final
    states from one device's; ``sysid``: ``trajectories`` box slides (closed-form data,
    a 400-sample box): the residual and Jacobian (segments split) and the scan's batch of
    16 parameter vectors (vectors split), times and the largest differences from one
    device's. ``first_s`` includes compiling (each device count is its own program).
    On forced host devices (``XLA_FLAGS=--xla_force_host_platform_device_count=8``) every
    device shares the machine's cores: this measures correctness and overhead, not speed."""
    enable_float64()
    setup = load_scene("bunny-drop")
    sc, s0, p = setup.scene, setup.state0, setup.params
    batch = batch or (4096 if jax.default_backend() == "gpu" else 64)
    qpos, qvel = _drops(batch, sc, s0)
    run = sharding.sharded_vmap(lambda q, v: rollout_arrays(sc, State(q, v), None, p, steps)[0][-1])
    box = build(BoxField((0.1, 0.1, 0.05), edge_width=0.002), mass=1.0, num_samples=400, mesh_resolution=0,
                name="box")
    scene = compose([DanoObject("box", box, (0, 0, 0.05))], dt=0.0025)
    problem = SysIdProblem(scene, analytic_slides(0, 0.05, trajectories), [FitParameter("sliding_friction", 0.3, 0.0,
                                                                                        2.0)],
                           weights=Weights((1.0, 1.0, 0.0), 0.0), substeps=4)
    theta, thetas = problem.initial(), np.linspace(0.05, 1.5, 16)[:, None]
    out: dict = {"backend": jax.default_backend(), "available_devices": jax.local_device_count(),
                 "processes": jax.process_count(), "cpu_count": os.cpu_count(),
                 "rollouts": {"batch": batch, "steps": steps}, "sysid": {"trajectories": trajectories,
                                                                         "residuals": problem.num_residuals,
                                                                         "scan_batch": len(thetas)}}
    ref = None
    for n in _device_counts(sharding.devices_in_use()):
        with sharding.use_devices(n):
            roll = _time(lambda: jax.block_until_ready(run(qpos, qvel)), repeats)
            final = np.asarray(run(qpos, qvel))
            jac = _time(lambda: problem.residuals_and_jacobian(theta), repeats)
            r, J = problem.residuals_and_jacobian(theta)
            scan = _time(lambda: problem.batch_residuals(thetas), repeats)
            R = problem.batch_residuals(thetas)
        if ref is None:
            ref = final, r, J, R
        roll["env_steps_per_s"] = batch * steps / roll["median_s"]
        roll["max_abs_diff_from_one_device"] = float(np.max(np.abs(final - ref[0])))
        jac["max_abs_diff_from_one_device"] = max(float(np.max(np.abs(r - ref[1]))), float(np.max(np.abs(J - ref[2]))))
        scan["max_abs_diff_from_one_device"] = float(np.max(np.abs(R - ref[3])))
        out["rollouts"][f"devices_{n}"] = roll
        out["sysid"][f"devices_{n}"] = {"residuals_and_jacobian": jac, "scan_batch": scan}
    return out


#: Ranges of the random drops of :func:`bench_energy`: the paper's Table I ranges for the
#: impact spring and damper (log-uniform), sliding friction up to 1; the other parameters
#: up to a few times the paper's defaults (uniform).
def bench_energy(repeats: int = 1, drops: int = 1000, seed: int = 0, duration: float = 3.0,
                 batch: int | None = None, contact_model: str = "centroid") -> dict:
    """Energy check of the contact solve (:func:`dano.experiments.energy.energy_check`):
    ``drops`` random paper-bunny drops; counts of non-finite, diverged and energy-gaining runs."""
    del repeats
    return energy_check(drops=drops, seed=seed, duration=duration, batch=batch, contact_model=contact_model)


def bench_trajopt(repeats: int = 3) -> dict:
    """Trajectory optimisation, task push-sphere (T = 60, nx = 26, nu = 6; float64):
    the parts of one iLQR iteration (``expand``: dynamics Jacobians by forward-mode AD of
    the step, vmapped over the horizon, and the cost expansion; ``backward``: the Riccati
    pass; ``forward``: one line-search rollout), each timed separately on the plain push,
    and one full solve from the plain push (iterations, time to convergence, time per
    iteration, compile time); with ``$MENAGERIE_ROOT``, a full solve of push-panda too."""
    task = push_sphere_task(PushSphereConfig())
    fns = _compiled(task.problem)
    x0, U, p = jnp.asarray(task.x0), jnp.asarray(task.U_plain), task.problem_params()
    lam = Multipliers(*(jnp.zeros(s, x0.dtype) for s in fns.sizes(x0, U, p)))
    mu = jnp.asarray(10.0, x0.dtype)
    X = fns.evaluate(x0, U, lam, mu, p)[0]
    E = fns.expand(X, U, lam, mu, p)
    K, k, _, _ = fns.backward(*E, jnp.asarray(0.0, x0.dtype))
    out = {
        "expand": _time(lambda: jax.block_until_ready(fns.expand(X, U, lam, mu, p)), repeats),
        "backward": _time(lambda: jax.block_until_ready(fns.backward(*E, jnp.asarray(0.0, x0.dtype))), repeats),
        "forward": _time(lambda: jax.block_until_ready(fns.forward(x0, X, U, K, k, 1.0, lam, mu, p)), repeats),
    }
    out["push_sphere_solve"] = _solve_summary(solve_task(task))
    if os.environ.get("MENAGERIE_ROOT"):
        out["push_panda_solve"] = _solve_summary(solve_task(push_panda_task(PushPandaConfig())))
    else:
        out["push_panda_solve"] = "skipped: set MENAGERIE_ROOT"
    return out


def _solve_summary(sol) -> dict:
    per = sol.wall_time_s - sol.compile_time_s
    every = sol.iterations + sum(r["iterations"] for r in sol.restarts)  # (the seconds count every solve's)
    return {"iterations": sol.iterations, "status": sol.status, "wall_time_s": sol.wall_time_s,
            "compile_time_s": sol.compile_time_s, "s_per_iteration": per / max(every, 1),
            "max_violation": sol.max_violation, "restarts": list(sol.restarts)}


def environment() -> dict:
    return {
        "dano": __version__,
        "jax": jax.__version__,
        "numpy": np.__version__,
        "backend": jax.default_backend(),
        "devices": [str(d) for d in jax.devices()],
        "machine": platform.machine(),
        "processor": platform.processor(),
        "python": platform.python_version(),
        "time": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "devices_in_use": sharding.devices_in_use(),
        "processes": jax.process_count(),
        "cpu_count": os.cpu_count(),
    }


def _shared_data() -> Path | None:
    """``$DANO_SHARED_DATA`` or ``../shared/data`` beside the working folder, if present."""
    path = Path(os.environ.get("DANO_SHARED_DATA", Path.cwd().parent / "shared" / "data"))
    return path if path.is_dir() else None


def bench_nerf(repeats: int = 1, minutes: float = 3.0, eval_at: tuple[float, ...] = (1.0,),
               loop_minutes: float = 3.0) -> dict:
    """Fields from images: training on the real ``lego_100px.npz`` (90 views, 10 held out)
    for ``minutes`` (held-out PSNR at ``eval_at`` minutes and at the end, rays/s, one process
    with XLA's default threads), and the ground-truth loop (:mod:`dano.experiments.nerf_loop`) on
    ``bunny_lowpoly.obj`` and ``spot.obj`` with ``loop_minutes`` of training each. Needs
    the shared data (``$DANO_SHARED_DATA`` or ``../shared/data``). 0 minutes skips a part."""
    data_dir = _shared_data()
    if data_dir is None:
        return {"skipped": "set DANO_SHARED_DATA to the folder holding nerf/ and meshes/"}
    out = {}
    if minutes > 0:
        data = load_dataset(data_dir / "nerf" / "lego_100px.npz")
        train_set, held = data.split(10)
        config = TrainConfig(minutes=minutes, eval_at_minutes=tuple(eval_at))
        result = train(train_set, config, heldout=held)
        out["lego"] = {"minutes": minutes, "psnr_heldout": result.psnr_heldout, "psnr_at_minutes": result.psnr_at,
                       "rays_per_s": result.rays_per_s, "steps": result.steps, "wall_time_s": result.wall_time_s,
                       "config": dataclasses.asdict(config)}
    if loop_minutes > 0:
        out["ground_truth_loop"] = [ground_truth_loop(data_dir / "meshes" / name, minutes=loop_minutes)
                                    for name in ("bunny_lowpoly.obj", "spot.obj")]
    return out


def bench_tracking(repeats: int = 1, curve: bool = True, colour_minutes: float = 0.0) -> dict:
    """From video to physics (``dano real2sim synthetic-slide``): tracking time per frame, the
    two identifications' results and wall times; the tracking success rate against the
    size of the initial pose error (:func:`tracking_success_curve`, 36 starts); with
    ``colour_minutes`` > 0, photometric tracking (:func:`tracking_colour`)."""
    with tempfile.TemporaryDirectory() as tmp:
        report = synthetic_slide_real2sim(Path(tmp) / "run", video_file=False)
        out = {k: v for k, v in report.items() if k not in ("per_frame", "pixels_fit", "track_config")}
        out["per_frame"] = report["per_frame"]
        if curve:
            out["success_curve"] = tracking_success_curve(Path(tmp) / "run" / "video")
        if colour_minutes > 0:
            out["colour_term"] = tracking_colour(Path(tmp) / "run" / "video", tmp, colour_minutes)
    return out


SUITES = {"build": bench_build, "sim": bench_sim, "sysid": bench_sysid, "latency": bench_latency,
          "batched": bench_batched, "scaling": bench_scaling, "sharded": bench_sharded,
          "trajopt": bench_trajopt, "energy": bench_energy, "nerf": bench_nerf, "tracking": bench_tracking}


def run(suites: list[str] | None = None, repeats: int = 3, options: dict | None = None) -> dict:
    """Run the named suites (default all) and return one JSON-able dict; options: per-suite
    keyword arguments, e.g. ``{"energy": {"drops": 100}}``."""
    names = suites or list(SUITES)
    options = options or {}
    return {"environment": environment(), **{n: SUITES[n](repeats=repeats, **options.get(n, {})) for n in names}}


@dataclass(frozen=True)
class BenchConfig:
    """Run the benchmarks (wall times; medians of repeats, first compiling call separate)."""

    json_: Annotated[bool, tyro.conf.arg(name="json")] = False
    """print one JSON object."""
    suite: tuple[str, ...] = ()
    """suites to run (default all): build, sim, sysid, latency (time to first result of five commands, cold and
    warm compilation cache), batched, scaling (dano and plain MJX, float32 and float64, B up to 262,144 on a GPU,
    each point in its own process), sharded (batches split over 1, 2, 4, ... devices:
    correctness and overhead), trajopt, energy, nerf (fields from images; needs the shared data, see
    benchmarks/README.md), tracking."""
    devices: int | None = None
    """local devices that batched suites (batched, sharded, energy) split their batches over (default: all of
    this process's; see docs/scaling.md)."""
    repeats: int = 3
    """timed repeats after the first call."""
    drops: int = 1000
    """random bunny drops of the energy suite."""
    seed: int = 0
    """random seed of the energy suite's drops."""
    contact_model: str = "centroid"
    """contact model of the energy suite (centroid or per_sample)."""
    nerf_minutes: float = 3.0
    """training time of the nerf suite's lego run (PSNR also at 1 minute)."""
    nerf_loop_minutes: float = 3.0
    """training time per mesh of the nerf suite's ground-truth loop (0: skip it)."""
    tracking_colour_minutes: float = 0.0
    """tracking suite: also train a radiance field of the slide's bunny this long and track 15 frames
    photometrically with colour weights 0, 0.02, 0.1 and 1 (0: skip it)."""
    cube_data: Path | None = None
    """sysid suite: also time the contactnets-cube identification on this ContactNets .npz (not shipped with
    dano)."""
    cube_tosses: int = 10
    """sysid suite: tosses of that run."""
    batches: tuple[int, ...] = ()
    """batch sizes of the batched and scaling suites, each 1 to 1048576 (default: per backend,
    benchmarks/README.md)."""
    scaling_timeout: float = 300.0
    """scaling suite: seconds one point (one engine, dtype and batch, in its own process, compile included) may
    run before it is reported as timed out."""
    out: Annotated[Path | None, tyro.conf.arg(aliases=("-o",))] = None
    """also write the JSON here."""

    def __post_init__(self):
        unknown = set(self.suite) - set(SUITES)
        if unknown:
            raise DanoError(f"unknown benchmark suite(s) {sorted(unknown)}; available: {', '.join(SUITES)}")
        if not 1 <= self.drops <= 1_000_000:
            raise DanoError(f"--drops must be 1 to 1000000, got {self.drops}")
        if not 1 <= self.repeats <= 1000:
            raise DanoError(f"--repeats must be 1 to 1000, got {self.repeats}")
        if self.contact_model not in CONTACT_MODELS:
            raise DanoError(f"unknown --contact-model {self.contact_model!r}; available: {', '.join(CONTACT_MODELS)}")
        if self.cube_data is not None and not Path(self.cube_data).is_file():
            raise DanoError(f"--cube-data {self.cube_data}: no such file")
        if not 2 <= self.cube_tosses <= 200:
            raise DanoError(f"--cube-tosses must be 2 to 200, got {self.cube_tosses}")
        if self.devices is not None:
            sharding.check_devices(self.devices, "--devices")
        if any(not 1 <= b <= 1_048_576 for b in self.batches):
            raise DanoError(f"--batches must be 1 to 1048576 each, got {list(self.batches)}")
        if not 1 <= self.scaling_timeout <= 86_400:
            raise DanoError(f"--scaling-timeout must be 1 to 86400 s, got {self.scaling_timeout}")


def bench_command(config: BenchConfig) -> dict:
    """``dano bench``: :func:`run` with ``config``'s suites and options, batches split over
    ``config.devices`` devices (default all)."""
    with sharding.use_devices(config.devices, "--devices"):
        return _bench_command(config)


def _bench_command(config: BenchConfig) -> dict:
    return run(list(config.suite) or None, repeats=config.repeats,
               options={"energy": {"drops": config.drops, "seed": config.seed, "contact_model": config.contact_model},
                        "sysid": {"cube_data": None if config.cube_data is None else str(config.cube_data),
                                  "cube_tosses": config.cube_tosses},
                        "nerf": {"minutes": config.nerf_minutes, "loop_minutes": config.nerf_loop_minutes,
                                 "eval_at": tuple(m for m in (1.0, 3.0) if m < config.nerf_minutes)},
                        "tracking": {"colour_minutes": config.tracking_colour_minutes},
                        "batched": {"batches": tuple(config.batches) or None},
                        "scaling": {"batches": tuple(config.batches) or None, "timeout_s": config.scaling_timeout}})
