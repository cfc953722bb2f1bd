"""One prepared run of the GPU checks of docs/scaling.md, for a lent GPU machine (the device tool).

Each point is :func:`dano.bench.scaling_point` in a fresh Python process (fresh compile, no
persistent cache), with its own XLA flags, compiler options and time limit; a point past its
limit has its Python stacks dumped (``faulthandler``) into ``OUT/stacks.txt`` and is recorded
as timed out. Results go, one JSON object per line, to ``OUT/points.jsonl`` as they come, so
that a run cut short keeps what it measured. Stages, in order of priority, each point skipped
when it could not finish within ``--budget`` seconds of the start:

1. B = 16,384 float32: dano with the Newton systems by LAPACK (the GPU's default) and by the
   unrolled LU, each with XLA's default command buffers and with while loops and conditionals
   in command buffers (CUDA graphs' conditional nodes: the Newton loop's test stays on the
   GPU); plain MJX on the bunny's hull with and without;
2. the fastest dano variant at B = 65,536 and 131,072, and in float64 at 16,384;
3. float32 at B = 131,072 again and again (the stalls of docs/scaling.md), with XLA's default
   autotuning and with ``--xla_gpu_autotune_level=0``.

Usage: ``python scripts/gpu_session.py OUT_DIR [--budget SECONDS]``.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

#: command buffers (CUDA graphs) for XLA's default commands plus while loops and conditionals
GRAPH_OPTIONS = {"xla_gpu_enable_command_buffer": "FUSION,CUBLAS,CUBLASLT,CUSTOM_CALL,CUDNN,CONDITIONAL,WHILE",
                 "xla_gpu_graph_min_graph_size": 1}
GRAPH_FLAGS = " ".join(f"--{k}={v}" for k, v in GRAPH_OPTIONS.items())

CHILD = """
import faulthandler, json, sys
stacks = open(sys.argv[1], "a")
stacks.write("=== " + sys.argv[2] + "\\n"); stacks.flush()
faulthandler.dump_traceback_later(float(sys.argv[3]), exit=False, file=stacks)
import dano.bench as b
r = b.scaling_point(**json.loads(sys.argv[4]))
faulthandler.cancel_dump_traceback_later()
print("RESULT " + json.dumps(r), flush=True)
"""


class Session:
    def __init__(self, out: Path, budget: float):
        self.out, self.budget, self.t0 = out, budget, time.time()
        self.points: dict[str, dict] = {}

    def elapsed(self) -> float:
        return time.time() - self.t0

    def point(self, key: str, timeout: float, xla_flags: str = "", **kwargs) -> dict | None:
        if self.elapsed() + timeout > self.budget:
            print(f"skip {key}: {self.elapsed():.0f} s of {self.budget:.0f} used", flush=True)
            return None
        env = dict(os.environ)
        if xla_flags:
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + xla_flags).strip()
        start = time.time()
        try:
            proc = subprocess.run([sys.executable, "-c", CHILD, str(self.out / "stacks.txt"), key,
                                   str(max(timeout - 5, 1)), json.dumps(kwargs)],
                                  capture_output=True, text=True, env=env, timeout=timeout)
            lines = [ln for ln in proc.stdout.splitlines() if ln.startswith("RESULT ")]
            r = json.loads(lines[-1][7:]) if lines else {"error": proc.stderr.strip().splitlines()[-8:]}
        except subprocess.TimeoutExpired:
            r = {"timed_out_s": timeout}
        r.update(key=key, xla_flags=xla_flags, kwargs=kwargs, started_unix=start, wall_s=time.time() - start)
        self.points[key] = r
        with open(self.out / "points.jsonl", "a") as f:
            f.write(json.dumps(r) + "\n")
        rate = r.get("env_steps_per_s")
        print(f"{key}: " + (f"{rate / 1e6:.3f}M env-steps/s, compile {r['compile_s']:.1f} s, "
                            f"median {r['median_s'] * 1e3:.0f} ms, trips {r.get('loop_trips')}, "
                            f"peak {r.get('peak_bytes')}, height {r.get('final_height_mean_m')}"
                            if rate else json.dumps({k: r[k] for k in r if k in ('timed_out_s', 'error')}))
              + f" [{r['wall_s']:.0f} s, at {self.elapsed():.0f} s]", flush=True)
        return r


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("out", type=Path)
    ap.add_argument("--budget", type=float, default=480.0)
    ap.add_argument("--batch", type=int, default=16384)
    ap.add_argument("--stall-batch", type=int, default=131072)
    ap.add_argument("--far-batch", type=int, default=65536)
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    s = Session(args.out, args.budget)
    env = subprocess.run([sys.executable, "-c", "import json, dano.bench as b; print(json.dumps(b.environment()))"],
                         capture_output=True, text=True)
    (args.out / "environment.json").write_text(env.stdout or env.stderr)
    print(env.stdout or env.stderr, flush=True)
    b = args.batch
    f32 = dict(engine="dano", dtype="float32", batch=b)
    # 1. the step's launches at B = 16,384
    s.point("dano_f32_lapack", 90, **f32, linear_solver="lapack")
    s.point("dano_f32_unrolled", 90, **f32, linear_solver="unrolled")
    s.point("dano_f32_lapack_graphs", 90, **f32, linear_solver="lapack", compiler_options=GRAPH_OPTIONS)
    s.point("dano_f32_unrolled_graphs", 90, **f32, linear_solver="unrolled", compiler_options=GRAPH_OPTIONS)
    s.point("mjx_f32", 90, engine="mjx", dtype="float32", batch=b)
    s.point("mjx_f32_graphs", 90, engine="mjx", dtype="float32", batch=b, compiler_options=GRAPH_OPTIONS)
    variants = {k: r for k, r in s.points.items() if k.startswith("dano_f32") and "env_steps_per_s" in r}
    best = max(variants, key=lambda k: variants[k]["env_steps_per_s"]) if variants else "dano_f32_lapack"
    opts = dict(s.points[best]["kwargs"]) if best in s.points else dict(f32, linear_solver="lapack")
    print(f"fastest at B={b}: {best}", flush=True)
    # 3 first (the stalls): default autotuning, then without
    sb = args.stall_batch
    for i in range(3):
        s.point(f"stall_default_{i + 1}", 45, engine="dano", dtype="float32", batch=sb, linear_solver="lapack")
    for i in range(3):
        s.point(f"stall_autotune0_{i + 1}", 45, xla_flags="--xla_gpu_autotune_level=0",
                engine="dano", dtype="float32", batch=sb, linear_solver="lapack")
    # 2. the fastest variant further out, and in float64
    for bb in (args.far_batch, sb):
        s.point(f"best_f32_{bb}", 60, **dict(opts, batch=bb))
    s.point("best_f64", 60, **dict(opts, dtype="float64"))
    s.point("dano_f64_lapack", 60, **dict(f32, dtype="float64", linear_solver="lapack"))
    s.point("best_f32_xla_flags", 60, xla_flags=GRAPH_FLAGS,
            **{k: v for k, v in opts.items() if k != "compiler_options"})
    print(f"done at {s.elapsed():.0f} s", flush=True)


if __name__ == "__main__":
    main()
