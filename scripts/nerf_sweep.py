"""Sweep of lego training configurations: held-out PSNR against the clock, per candidate.

Uses dano's public training API exactly as ``bench_nerf`` does (``load_dataset`` ->
``split(10)`` -> ``train(train_set, TrainConfig(...), heldout=held)``), with each candidate a
set of overrides of ``TrainConfig`` fields (``"rays_per_step"``) and ``FieldConfig`` fields
(``"field.levels"``). Held-out PSNR is measured at 1/3, 2/3 of ``--minutes`` (via
``eval_at_minutes``) and at the end. After every config the JSON is rewritten, so a run
that times out still leaves the configs done so far.

    python scripts/nerf_sweep.py /path/lego_100px.npz out.json --minutes 3 --configs default,res256
    python scripts/nerf_sweep.py data.npz out.json --configs mine --override 'mine:field.levels=8,rays_per_step=8192'

Used for the H100 run of 2026-11-25 (``benchmarks/results-gpu-h100.json``) and the CPU pixel-jitter
A/B (``benchmarks/nerf-cpu.json``); docs/fields-from-images.md.
    python scripts/nerf_sweep.py data.npz out.json --dry-run     # build every config, train nothing
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
import traceback

import jax
import numpy as np

from dano.nerf import FieldConfig, TrainConfig, load_dataset, train

# Candidates: overrides of TrainConfig ("name") and FieldConfig ("field.name") fields only.
CANDIDATES: dict[str, dict] = {
    # the library defaults (4 levels x 4 features, 2^18, 16-128, MLP 32, 4096 rays x 12, 256 across)
    "default": {},
    # only the finest resolution: 128 -> 256 (levels 16, 40, 101, 256). Same levels, features,
    # table and samples, so the same cost per sample on any device (CPU-neutral); tests whether
    # the finest cell (3/128 = 0.023 units, ~0.8 of a 100-px pixel footprint at the object) is the ceiling.
    "res256": {"field.max_resolution": 256},
    # more capacity + finer sampling + a bigger batch (the GPU is far from saturated at 49k samples/step)
    "wide8": {"field.levels": 8, "field.features": 4, "field.log2_table_size": 19, "field.max_resolution": 512,
              "field.hidden": 64, "field.color_hidden": 64,
              "rays_per_step": 8192, "samples_across": 384, "samples_per_ray": 20},
    # instant-ngp-like encoding (16 x 2, 2^19, 64-wide MLPs), finest 512 (~4 cells per pixel footprint,
    # not ngp's 2048: the views are 100 px), finer marching, 16k rays per step, 128^3 occupancy grid
    "ngp16": {"field.levels": 16, "field.features": 2, "field.log2_table_size": 19, "field.max_resolution": 512,
              "field.hidden": 64, "field.color_hidden": 64,
              "rays_per_step": 16384, "samples_across": 512, "samples_per_ray": 24, "occupancy_resolution": 128},
}

_TRAIN_FIELDS = {f.name: f for f in dataclasses.fields(TrainConfig)}
_FIELD_FIELDS = {f.name: f for f in dataclasses.fields(FieldConfig)}
_FIXED = {"minutes", "eval_at_minutes", "field"}  # set by the sweep itself


def _coerce(value, like):
    """A string from the command line as the type of the default ``like``."""
    if not isinstance(value, str):
        return value
    if isinstance(like, bool):
        return value.lower() in ("1", "true", "yes")
    if isinstance(like, int):
        return int(value)
    if isinstance(like, float) or like is None:
        return None if value.lower() == "none" else float(value)
    return value


def build_config(overrides: dict, minutes: float, eval_at: tuple[float, ...]) -> TrainConfig:
    """TrainConfig of the defaults with ``overrides``; raises KeyError on an unknown field."""
    base_train, base_field = TrainConfig(), FieldConfig()
    train_kw, field_kw = {}, {}
    for key, value in overrides.items():
        if key.startswith("field."):
            name = key[len("field."):]
            if name not in _FIELD_FIELDS:
                raise KeyError(f"unknown FieldConfig field {name!r} (have {sorted(_FIELD_FIELDS)})")
            field_kw[name] = _coerce(value, getattr(base_field, name))
        else:
            if key not in _TRAIN_FIELDS or key in _FIXED:
                raise KeyError(f"unknown or fixed TrainConfig field {key!r} (have {sorted(set(_TRAIN_FIELDS) - _FIXED)})")
            train_kw[key] = _coerce(value, getattr(base_train, key))
    return TrainConfig(minutes=minutes, eval_at_minutes=tuple(eval_at), field=FieldConfig(**field_kw), **train_kw)


def _parse_override(text: str) -> tuple[str, dict]:
    name, _, body = text.partition(":")
    if not body:
        raise SystemExit(f"--override {text!r}: expected NAME:key=value,key=value")
    pairs = {}
    for item in body.split(","):
        key, _, value = item.partition("=")
        pairs[key.strip()] = value.strip()
    return name.strip(), pairs


def _recent(log: list, fraction: float = 0.1) -> dict:
    """Training PSNR (from the mean MSE), complete-ray fraction and samples per ray over the
    last ``fraction`` of the steps: train vs held-out PSNR tells under- from overfitting."""
    if not log:
        return {}
    tail = log[-max(1, int(len(log) * fraction)):]
    mse = np.mean([10.0 ** (-r["psnr_train"] / 10.0) for r in tail])
    return {"psnr_train_recent": float(-10.0 * math.log10(max(mse, 1e-12))),
            "complete_recent": float(np.mean([r["complete"] for r in tail])),
            "samples_per_ray_recent": float(np.mean([r["samples_per_ray"] for r in tail])),
            "lr_final": float(tail[-1]["lr"])}


def run_one(name: str, overrides: dict, train_set, held, minutes: float, fractions: tuple[float, ...],
            seed: int, progress_s: float) -> dict:
    eval_at = tuple(round(minutes * f, 6) for f in fractions if 0 < f < 1)
    config = build_config({**overrides, **({"seed": seed} if seed else {})}, minutes, eval_at)
    print(f"\n=== {name}: {json.dumps(overrides)}", flush=True)
    last = [0.0]

    def progress(rec):
        if rec["elapsed_s"] - last[0] >= progress_s:
            last[0] = rec["elapsed_s"]
            print(f"  [{name}] step {rec['step']:6d}  t {rec['elapsed_s']:6.1f} s  train {rec['psnr_train']:5.2f} dB  "
                  f"lr {rec['lr']:.2e}  complete {rec['complete']:.3f}  spr {rec['samples_per_ray']:.1f}", flush=True)

    wall0 = time.perf_counter()
    result = train(train_set, config, heldout=held, progress=progress)
    wall = time.perf_counter() - wall0
    psnr_at = {k: float(v) for k, v in result.psnr_at.items()}
    psnr_at[f"{minutes:g}"] = float(result.psnr_heldout)
    out = {
        "name": name, "overrides": overrides,
        "psnr_at_minutes": psnr_at, "psnr_heldout": float(result.psnr_heldout),
        "rays_per_s": float(result.rays_per_s), "steps": int(result.steps),
        "train_clock_s": float(result.wall_time_s), "wall_s": wall,
        "first_step_s": float(result.log[0]["elapsed_s"]) if result.log else None,  # ~ compilation
        "occupied_fraction": float(result.occupancy.fraction_occupied()),
        "resolutions": [int(r) for r in result.field.config.resolutions()],
        "params": int(sum(np.size(x) for x in jax.tree_util.tree_leaves(result.field.params))),
        **_recent(result.log),
        "config": dataclasses.asdict(config),
    }
    at = "  ".join(f"{k} min {v:.2f} dB" for k, v in sorted(psnr_at.items(), key=lambda kv: float(kv[0])))
    print(f"=== {name}: {at} | {out['rays_per_s']:,.0f} rays/s, {out['steps']} steps, "
          f"train {out.get('psnr_train_recent', float('nan')):.2f} dB (last 10%), wall {wall:.0f} s", flush=True)
    return out


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("data", help="lego_100px.npz (or any dataset dano.nerf.load_dataset reads)")
    p.add_argument("out", help="JSON to write (rewritten after each config)")
    p.add_argument("--minutes", type=float, default=3.0, help="training clock per config (default 3)")
    p.add_argument("--configs", default="", help="comma-separated candidate names (default: all); "
                   f"known: {','.join(CANDIDATES)}")
    p.add_argument("--override", action="append", default=[],
                   help="extra candidate NAME:key=value,... (TrainConfig fields, or field.<FieldConfig field>); repeatable")
    p.add_argument("--fractions", default="0.333333,0.666667",
                   help="held-out PSNR also at these fractions of --minutes (default 1/3,2/3)")
    p.add_argument("--holdout", type=int, default=10)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--progress-s", type=float, default=30.0, help="seconds between progress lines")
    p.add_argument("--dry-run", action="store_true", help="build and print each config, train nothing")
    args = p.parse_args(argv)

    candidates = dict(CANDIDATES)
    extra = [_parse_override(t) for t in args.override]
    candidates.update(extra)
    names = [n.strip() for n in args.configs.split(",") if n.strip()] or list(CANDIDATES) + [n for n, _ in extra]
    unknown = [n for n in names if n not in candidates]
    if unknown:
        raise SystemExit(f"unknown configs {unknown}; known: {list(candidates)}")
    fractions = tuple(float(f) for f in args.fractions.split(",") if f.strip())
    for n in names:  # fail fast on a bad override, before any training
        cfg = build_config(candidates[n], args.minutes, ())
        print(f"{n}: resolutions {cfg.field.resolutions().tolist()}, "
              f"{cfg.rays_per_step} rays x {cfg.samples_per_ray} samples/step, {cfg.samples_across} across", flush=True)
    if args.dry_run:
        return 0

    env = {"jax": jax.__version__, "backend": jax.default_backend(),
           "devices": [d.device_kind for d in jax.devices()], "python": platform.python_version(),
           "cpus": os.cpu_count(), "argv": sys.argv, "minutes": args.minutes, "data": args.data}
    print(json.dumps(env), flush=True)
    data = load_dataset(args.data)
    train_set, held = data.split(args.holdout)
    report = {"environment": env, "results": []}

    def write():
        tmp = args.out + ".tmp"
        with open(tmp, "w") as f:
            json.dump(report, f, indent=2)
        os.replace(tmp, args.out)

    for n in names:
        try:
            report["results"].append(run_one(n, candidates[n], train_set, held, args.minutes, fractions, args.seed,
                                             args.progress_s))
        except Exception as exc:  # e.g. out of memory: record it, go on
            traceback.print_exc()
            report["results"].append({"name": n, "overrides": candidates[n], "error": f"{type(exc).__name__}: {exc}"})
        write()
        jax.clear_caches()

    print("\nsummary (held-out dB by minute):", flush=True)
    for r in report["results"]:
        if "error" in r:
            print(f"  {r['name']:10s} ERROR {r['error'][:100]}", flush=True)
        else:
            at = "  ".join(f"{v:6.2f}@{k}" for k, v in sorted(r["psnr_at_minutes"].items(), key=lambda kv: float(kv[0])))
            print(f"  {r['name']:10s} {at}  {r['rays_per_s']:>12,.0f} rays/s  {r['steps']:7d} steps  "
                  f"train {r.get('psnr_train_recent', float('nan')):.2f}", flush=True)
    print(f"wrote {args.out}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
