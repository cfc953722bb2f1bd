"""The energy check of the contact solve (paper Table I's parameter ranges): random bunny
drops simulated unactuated, counting runs that turn non-finite, diverge or gain energy."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from .. import sharding
from ..contact import ContactParams
from ..pose import quat_to_matrix, random_quats
from ..sim import make_data, scan_steps
from ..sim.implicit import NewtonConfig, iteration_limit
from ..sim.energy import mechanical_energy
from ..sim.rollout import first_divergence
from ..sim.scenes import load_scene


ENERGY_RANGES = {
    "impact_spring": (1e4, 1e5), "impact_damper": (1e5, 1e6), "sliding_friction": (0.0, 1.0),
    "sliding_drag": (0.0, 0.2), "torsional_friction": (0.0, 0.05), "torsional_drag": (0.0, 0.05),
    "rolling_friction": (0.0, 0.05), "rolling_drag": (0.0, 0.05),
}


def random_drops(scene, drops: int, seed: int = 0, height=(0.3, 1.5), max_speed: float = 5.0,
                 max_spin: float = 10.0):
    """Random drops of the scene's single DANO: (qpos0 (B, 7), qvel0 (B, 6), ContactParams
    with (B, 1) fields). Orientation uniform; the lowest sample starts ``height`` [m] above
    the ground; velocity and spin uniform in direction, magnitude uniform up to
    ``max_speed`` [m/s] and ``max_spin`` [rad/s]; parameters from :data:`ENERGY_RANGES`."""
    rng = np.random.default_rng(seed)
    quat = random_quats(rng, drops)
    pts = np.array(scene.assets[0].points)
    lowest = -np.min(pts @ quat_to_matrix(quat)[:, 2, :].T, axis=0)  # heights: the matrices' last rows
    z = lowest + rng.uniform(*height, drops)
    unit = lambda n: (lambda v: v / np.linalg.norm(v, axis=1, keepdims=True))(rng.normal(size=(n, 3)))  # noqa: E731
    v = unit(drops) * rng.uniform(0, max_speed, (drops, 1))
    w = unit(drops) * rng.uniform(0, max_spin, (drops, 1))
    qpos = np.concatenate([np.zeros((drops, 2)), z[:, None], quat], axis=1)
    params = {}
    for name, (lo, hi) in ENERGY_RANGES.items():
        if name in ("impact_spring", "impact_damper"):
            val = np.exp(rng.uniform(np.log(lo), np.log(hi), drops))
        else:
            val = rng.uniform(lo, hi, drops)
        params[name] = jnp.asarray(val[:, None], dtype=scene.dtype)
    return (jnp.asarray(qpos, dtype=scene.dtype), jnp.asarray(np.concatenate([v, w], axis=1), dtype=scene.dtype),
            ContactParams(**params))


def energy_check(drops: int = 1000, seed: int = 0, duration: float = 3.0,
                 batch: int | None = None, contact_model: str = "centroid",
                 newton: NewtonConfig = NewtonConfig()) -> dict:
    """Energy check of the contact solve: ``drops`` random paper-bunny drops (see
    :func:`random_drops`, h = 0.01 s, ``duration`` s, unactuated, vmapped in batches),
    counting runs that become non-finite, diverge (speed > 1000 or an overlap above half
    the mass) or whose kinetic + potential energy ever exceeds its initial value by more
    than 1 % (``energy_rises``; the five worst in ``worst_runs``, the first 20 non-finite
    drops by index in ``nonfinite_drops``); ``max_energy_ratio`` is the largest max_t E(t)/E(0);
    ``unconverged_steps``: steps whose Newton solve used all its iterations (both tries' where
    it has a second, :attr:`~dano.sim.NewtonConfig.second_try`); ``failed_steps``: steps that
    failed (not converged, or a pair turned too far: :attr:`~dano.sim.dynamics.StepInfo.failed`,
    taken again in substeps where ``newton`` allows them), ``failed_drops`` the drops that had one.
    contact_model: of the bunny/ground pair. batch: drops per vmapped call (default 50 for
    the centroid model; 1, unbatched, for per_sample, whose gathering of the samples in
    reach only pays off outside ``jax.vmap``); a batched call is split over the devices in
    use (:mod:`dano.sharding`; the batch rounded up to a multiple of their number). newton:
    the step's solver settings (``NewtonConfig(reverse_mode=False)``: forward-only steps, each
    whose Newton solve fails taken again in substeps, docs/simulation.md)."""

    setup = load_scene("bunny-drop", contact_model=contact_model)
    sc, base = setup.scene, setup.params
    steps = int(round(duration / sc.dt))
    qpos0, qvel0, cparams = random_drops(sc, drops, seed)

    def one(q, v, p):
        d = make_data(sc, q, v)
        _, qpos, qvel, psi, iters, failed = scan_steps(sc, base.replace(contact=p), d,
                                                       jnp.zeros((steps, sc.nu), sc.dtype),
                                                       jnp.zeros((steps, sc.nv), sc.dtype), newton, failures=True)
        return qpos, qvel, psi, iters, failed

    if batch is None:
        batch = 1 if contact_model == "per_sample" else 50
    if batch == 1:
        single = jax.jit(one)
        run = lambda q, v, p: tuple(x[None] for x in single(q[0], v[0], jax.tree_util.tree_map(lambda a: a[0], p)))  # noqa: E731
    else:
        batch = sharding.padded_size(batch, sharding.shards_for(batch))
        run = sharding.sharded_vmap(one)
    out = {"drops": drops, "nonfinite": 0, "diverged": 0, "energy_rises": 0, "max_energy_ratio": 0.0,
           "seed": seed, "steps": steps, "dt": sc.dt, "contact_model": contact_model,
           "unconverged_steps": 0, "failed_steps": 0, "max_newton_iterations": 0, "batch": batch,
           "devices": 1 if batch == 1 else sharding.shards_for(batch)}
    t0 = time.perf_counter()
    worst, nonfinite, failed_runs = [], [], []
    for start in range(0, drops, batch):
        sl = slice(start, min(start + batch, drops))
        n = sl.stop - sl.start
        pad = lambda x: jnp.concatenate([x, jnp.repeat(x[-1:], batch - n, axis=0)]) if n < batch else x  # noqa: E731
        p = jax.tree_util.tree_map(lambda x: pad(x[sl]), cparams)
        qpos, qvel, psi, iters, failed = (np.asarray(a)[:n] for a in run(pad(qpos0[sl]), pad(qvel0[sl]), p))
        limit = iteration_limit(sc, newton)
        out["unconverged_steps"] += int(np.sum(iters >= limit))
        out["failed_steps"] += int(failed.sum())
        failed_runs.extend(start + i for i in np.flatnonzero(failed.any(axis=1)))
        out["max_newton_iterations"] = max(out["max_newton_iterations"], int(iters.max()))
        E = mechanical_energy(sc, qpos, qvel)
        for i in range(n):
            if not (np.all(np.isfinite(qpos[i])) and np.all(np.isfinite(qvel[i]))):
                out["nonfinite"] += 1
                nonfinite.append(start + i)
                continue
            params_i = base.replace(contact=jax.tree_util.tree_map(lambda x: x[start + i], cparams))
            if first_divergence(sc, params_i, qpos[i], qvel[i], psi[i])[0] is not None:
                out["diverged"] += 1
            ratio = float(np.max(E[i]) / E[i, 0])
            out["max_energy_ratio"] = max(out["max_energy_ratio"], ratio)
            if ratio > 1.01:
                out["energy_rises"] += 1
                worst.append((ratio, start + i))
    out["wall_time_s"] = time.perf_counter() - t0
    out["env_steps_per_s"] = drops * steps / out["wall_time_s"]
    out["worst_runs"] = [{"drop": i, "energy_ratio": r} for r, i in sorted(worst, reverse=True)[:5]]
    out["nonfinite_drops"] = nonfinite[:20]
    out["failed_drops"] = [int(i) for i in failed_runs]
    return out
