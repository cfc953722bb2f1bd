"""One prepared run of the GPU checks of docs/scaling.md, for a lent GPU machine (the device tool).

Each point is :func:`dano.bench.scaling_point` in a fresh Python process
(:func:`dano.bench.scaling_point_in_process`: fresh compile, no persistent cache), with its own
XLA flags, compiler options and time limit. While a point runs,
``nvidia-smi`` samples the GPU every 0.5 s into ``OUT/smi.csv`` (each line tagged with the
point); a point past its limit has its Python stacks dumped (``faulthandler``) into
``OUT/stacks.txt`` and a full ``nvidia-smi -q`` snapshot appended there before it is killed,
and is recorded as timed out. Results go, one JSON object per line, to ``OUT/points.jsonl`` as
they come, so that a run cut short keeps what it measured. Stages (``--stages``, in the order
given), each point skipped when it could not finish within ``--budget`` seconds of the start:

* ``launches``: B = 16,384 float32: dano with the Newton systems by LAPACK and by the unrolled
  LU, each with XLA's default command buffers (``{}``) and with dano's rollout options (while
  loops and conditionals in CUDA graphs: :func:`dano.sim.batched_compiler_options`, the
  default); plain MJX on the bunny's hull with XLA's defaults and with the graphs;
* ``stalls``: float32 at ``--stall-batch`` (131,072) again and again (the stalls of
  docs/scaling.md): dano's defaults, then ``--xla_gpu_deterministic_ops=true``, then LAPACK
  without graphs (the configuration of the first stalls);
* ``far``: dano's defaults at ``--far-batch`` (65,536), 131,072 and 262,144 float32 and at
  16,384 and 131,072 float64;
* with ``--baseline DIR`` (a directory holding an earlier dano's ``src``, e.g. ``git archive
  REV src | tar -x -C DIR``, carried to the machine): the ``launches`` stage also times dano's
  defaults with that dano first on PYTHONPATH, between two runs of this one (the same machine,
  the same call: a fair comparison; each point records its ``env``, and this dano's points
  their ``dano_path``);
* ``table``: the scaling table, dano's defaults beside plain MJX on the bunny's hull, float32
  and float64, at each B of ``--table-batches`` (16,384, 65,536 and 262,144; the largest with
  one timed run instead of two), the four points of a B one after another in this call;
* ``dump``: XLA's optimised program of dano's B = 16,384 float32 rollout
  (``--xla_dump_to``, as text) into ``OUT/hlo_dump.tar.gz``: how many kernels a Newton
  iteration launches, to be counted offline.

Usage: ``python scripts/gpu_session.py OUT_DIR [--budget SECONDS] [--stages launches,stalls,far,table,dump]
[--baseline DIR]``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tarfile
import time
from pathlib import Path

from dano.bench import scaling_point_in_process

SMI_FIELDS = "timestamp,utilization.gpu,utilization.memory,memory.used,clocks.sm,power.draw,pstate"


class Session:
    def __init__(self, out: Path, budget: float):
        self.out, self.budget, self.t0 = out, budget, time.time()
        self.points: dict[str, dict] = {}

    def elapsed(self) -> float:
        return time.time() - self.t0

    def _sampler(self, key: str):
        """nvidia-smi every 0.5 s, each line prefixed by the point's key (None without nvidia-smi)."""
        try:
            smi = subprocess.Popen(["nvidia-smi", f"--query-gpu={SMI_FIELDS}", "--format=csv,noheader", "-lms", "500"],
                                   stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
        except OSError:
            return None
        with open(self.out / "smi.csv", "a") as log:  # (the child keeps its own copy of the handle)
            tagger = subprocess.Popen(["sed", "-u", f"s/^/{key}, /"], stdin=smi.stdout, stdout=log)
        smi.stdout.close()
        return smi, tagger

    def point(self, key: str, timeout: float, xla_flags: str = "", env: dict | None = None, **kwargs) -> dict | None:
        if self.elapsed() + timeout > self.budget:
            print(f"skip {key}: {self.elapsed():.0f} s of {self.budget:.0f} used", flush=True)
            return None
        stacks = self.out / "stacks.txt"
        with open(stacks, "a") as f:
            f.write(f"=== {key}\n")
        start = time.time()

        def gpu_state():  # the GPU's state while the point hangs
            with open(stacks, "a") as f:
                f.write(f"--- nvidia-smi -q of {key} at {time.time() - start:.0f} s\n")
                f.flush()
                subprocess.run(["nvidia-smi", "-q", "-d", "UTILIZATION,PERFORMANCE,CLOCK,MEMORY,PIDS"],
                               stdout=f, stderr=subprocess.STDOUT, check=False)

        sampler = self._sampler(key)
        try:
            r = scaling_point_in_process(timeout, xla_flags, str(stacks), gpu_state, env, **kwargs)
        finally:
            if sampler:
                for p in sampler:
                    p.terminate()
                    p.wait()
        r.update(key=key, xla_flags=xla_flags, env=env or {}, kwargs=kwargs, started_unix=start)
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
    ap.add_argument("--stages", default="launches,stalls,far")
    ap.add_argument("--batch", type=int, default=16384)
    ap.add_argument("--stall-batch", type=int, default=131072)
    ap.add_argument("--far-batch", type=int, default=65536)
    ap.add_argument("--attempts", type=int, default=3)
    ap.add_argument("--table-batches", default="16384,65536,262144")
    ap.add_argument("--baseline", type=Path, default=None, help="an earlier dano's checkout (its src/) to time beside")
    args = ap.parse_args()
    if args.baseline is not None and not (args.baseline / "src" / "dano" / "__init__.py").is_file():
        raise SystemExit(f"--baseline {args.baseline}: no src/dano/__init__.py there")
    args.out.mkdir(parents=True, exist_ok=True)
    s = Session(args.out, args.budget)
    env = subprocess.run([sys.executable, "-c", "import json, dano.bench as b; print(json.dumps(b.environment()))"],
                         capture_output=True, text=True)
    (args.out / "environment.json").write_text(env.stdout or env.stderr)
    print(env.stdout or env.stderr, flush=True)
    b, sb = args.batch, args.stall_batch
    f32 = dict(engine="dano", dtype="float32")
    graphs = subprocess.run([sys.executable, "-c", "import json; from dano.sim import batched_compiler_options as o; "
                             "print(json.dumps(o()))"], capture_output=True, text=True, env=dict(os.environ))
    if graphs.returncode:
        raise SystemExit(f"dano.sim.batched_compiler_options() failed: {graphs.stderr.strip()[-500:]}")
    graph_options = json.loads(graphs.stdout)
    print(f"dano's rollout options here: {graph_options}", flush=True)
    for stage in args.stages.split(","):
        if stage == "launches":  # the step's launches at B = 16,384
            for solver in ("lapack", "unrolled"):
                s.point(f"dano_f32_{solver}", 90, **f32, batch=b, linear_solver=solver, compiler_options={})
                s.point(f"dano_f32_{solver}_graphs", 90, **f32, batch=b, linear_solver=solver)
            if args.baseline is not None:  # this dano, the earlier one, this dano again: same machine, same call
                path = os.pathsep.join(p for p in (str(args.baseline.resolve() / "src"), os.environ.get("PYTHONPATH"))
                                       if p)
                s.point("dano_f32_default", 90, **f32, batch=b)
                s.point("baseline_dano_f32_default", 90, env={"PYTHONPATH": path}, **f32, batch=b)
                s.point("dano_f32_default_again", 90, **f32, batch=b)
            s.point("mjx_f32", 90, engine="mjx", dtype="float32", batch=b)
            s.point("mjx_f32_graphs", 90, engine="mjx", dtype="float32", batch=b, compiler_options=graph_options)
        elif stage == "stalls":
            for name, flags, kw in (("default", "", {}),
                                    ("deterministic", "--xla_gpu_deterministic_ops=true", {}),
                                    ("lapack_nographs", "", dict(linear_solver="lapack", compiler_options={}))):
                for i in range(args.attempts):
                    s.point(f"stall_{name}_{i + 1}", 45, xla_flags=flags, **f32, batch=sb, **kw)
        elif stage == "far":
            for bb in (args.far_batch, sb, 2 * sb):
                s.point(f"dano_f32_{bb}", 75, **f32, batch=bb)
            for bb in (b, sb):
                s.point(f"dano_f64_{bb}", 75, engine="dano", dtype="float64", batch=bb)
        elif stage == "table":  # dano beside plain MJX, both dtypes, B after B
            batches = [int(x) for x in args.table_batches.split(",")]
            for bb in batches:
                reps = 1 if bb == max(batches) else 2
                for dtype in ("float32", "float64"):
                    for engine in ("dano", "mjx"):
                        limit = 60 + bb * 200 * 3 / 2e6  # compile + 3 runs at 2M env-steps/s or more
                        s.point(f"table_{engine}_{dtype}_{bb}", limit, engine=engine, dtype=dtype, batch=bb,
                                repeats=reps)
        elif stage == "dump":  # XLA's optimised program of the B = 16,384 rollout, to count its kernels offline
            where = Path("/tmp/dano_xla_dump")
            shutil.rmtree(where, ignore_errors=True)
            s.point("dump_f32", 120, xla_flags=f"--xla_dump_to={where} --xla_dump_hlo_as_text", **f32, batch=b)
            kept = [p for p in where.glob("*jit_roll*") if p.suffix not in (".ll", ".ptx", ".o")]
            with tarfile.open(args.out / "hlo_dump.tar.gz", "w:gz") as tar:
                for p in kept:
                    tar.add(p, arcname=p.name)
            print(f"dumped {len(kept)} files of the rollout's program", flush=True)
        else:
            raise SystemExit(f"--stages: unknown stage {stage!r} (launches, stalls, far, table, dump)")
    print(f"done at {s.elapsed():.0f} s", flush=True)


if __name__ == "__main__":
    main()
