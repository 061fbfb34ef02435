"""The batched helium engine, the fused ABC loop and the main job on JAX's default backend.

Issue 15 asks for the batched engine and the fused ABC loop to be measured on a GPU where one
is available, with the GPU named.  This script times, on whatever backend JAX picks (``--cpu`` for a CPU
baseline on the same machine):

- the helium engine (``md.helium``, NPT, compiled segment timed on its second call) for the
  32-atom ``cpu`` preset and the 1000-atom ``paper`` preset over batch sizes, in system-steps
  and atom-steps per wall second (``benchmarks/engine_throughput.py``'s ``time_jax_md``);
  the ``paper`` preset maps over its members one by one by default (``vmap_width=1``, the CPU
  choice), so it is also timed with the whole batch under one ``vmap``;
- the fused PMC-ABC loop (``jaxabc.run_fused``) on the 2-D Gaussian of
  ``benchmarks/abc_overhead.py`` (x = theta + N(0, I), thresholds 6, 3, 1.5, 0.75) at
  several population sizes: the first run in the process (compilation included) and a second
  run (compiled programs reused), in microseconds per simulation;
- the main job ``jaxabc example helium`` as a child process (wall seconds, cold
  persistent compilation cache).

Every measurement that fails records its error instead of stopping the run.  Writes
``benchmarks/results/gpu_throughput.json`` (or ``--output``), one part per backend
(``--part``), so GPU and CPU rows of the same machine sit side by side.

Run: ``python -m benchmarks.gpu_throughput --part gpu`` on the GPU machine, then
``python -m benchmarks.gpu_throughput --part cpu --cpu --quick`` on the same one.  The main job
parts need the project pip-installed there (``python3 -m pip install --no-deps --no-index
--no-build-isolation -e .`` works offline): the helium example is an entry point, which a tree
run from ``PYTHONPATH`` does not register.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

T_START = time.perf_counter()
if "--cpu" in sys.argv:  # before JAX is imported
    os.environ["JAX_PLATFORMS"] = "cpu"
import jax  # noqa: E402
import numpy as np  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]

from benchmarks._common import RESULTS, command_line, write_result  # noqa: E402


def device_record() -> dict:
    """The device JAX runs on, by name."""
    d = jax.devices()[0]
    return {
        "platform": d.platform,
        "device_kind": d.device_kind,
        "num_devices": jax.device_count(),
        "jax": jax.__version__,
    }


def guarded(fn, *args, **kwargs) -> dict:
    """``fn(*args, **kwargs)``, or the error it raised (with the end of its traceback)."""
    t0 = time.perf_counter()
    try:
        out = fn(*args, **kwargs)
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}", "traceback": traceback.format_exc()[-2000:]}
    if isinstance(out, dict):
        out.setdefault("measured_in_s", time.perf_counter() - t0)
    return out


def engine_rows(preset_name: str, batches: list[int], num_blocks: int, vmap_all: bool) -> list[dict]:
    from benchmarks.engine_throughput import time_jax_md
    from md import helium

    rows = []
    for b in batches:
        preset = helium.get_preset(preset_name, vmap_width=None) if vmap_all else helium.get_preset(preset_name)
        row = guarded(time_jax_md, preset, b, num_blocks)
        row.update(preset=preset_name, num_atoms=preset.num_atoms, vmap_all=vmap_all, vmap_width=preset.vmap_width)
        for k in ("atom_steps_per_second_per_core", "cores"):
            row.pop(k, None)  # per-core rates mean nothing on an accelerator
        rows.append(row)
        print(json.dumps({k: row.get(k) for k in ("preset", "batch", "vmap_all", "system_steps_per_second")}))
    return rows


def fused_rows(sizes: list[int], thresholds: list[float], seed: int) -> list[dict]:
    import jaxabc

    def simulate(key, theta):
        return theta + jax.random.normal(key, theta.shape)

    prior = jaxabc.Uniform([-10.0, -10.0], [10.0, 10.0], names=("a", "b"))
    rows = []
    for n in sizes:
        row: dict = {"num_particles": n}
        for label in ("first_run", "second_run"):
            t0 = time.perf_counter()
            try:
                r = jaxabc.run_fused(
                    "pmcabc",
                    simulate,
                    prior,
                    np.zeros(2),
                    num_particles=n,
                    distance="euclidean",
                    seed=seed,
                    thresholds=thresholds,
                    num_steps=len(thresholds) + 1,
                    keep_summaries=False,
                )
            except Exception as exc:
                row[label] = {"error": f"{type(exc).__name__}: {exc}"}
                continue
            wall = time.perf_counter() - t0
            sims = int(r.num_simulations)
            mean = np.average(np.asarray(r.particles), axis=0, weights=np.asarray(r.weights))
            row[label] = {
                "wall_s": wall,
                "num_simulations": sims,
                "us_per_simulation": 1e6 * wall / sims,
                "posterior_mean": mean.tolist(),
            }
        rows.append(row)
        print(json.dumps(row))
    return rows


def main_job(timeout: float) -> dict:
    """Wall seconds of ``jaxabc example helium`` in a child process, cold XLA cache."""
    with tempfile.TemporaryDirectory() as tmp:
        path = os.pathsep.join(p for p in (str(ROOT), os.environ.get("PYTHONPATH", "")) if p)
        env = {**os.environ, "PYTHONPATH": path, "JAXABC_COMPILATION_CACHE": str(Path(tmp) / "xla")}
        code = "import sys; from jaxabc.cli import main; sys.exit(main(['example', 'helium']))"
        t0 = time.perf_counter()
        try:
            out = subprocess.run(
                [sys.executable, "-c", code], cwd=tmp, env=env, capture_output=True, text=True, timeout=timeout
            )
        except subprocess.TimeoutExpired:
            return {"error": f"timed out after {timeout} s"}
        wall = time.perf_counter() - t0
    return {
        "command": "jaxabc example helium",
        "wall_s": wall,
        "returncode": out.returncode,
        "stderr_tail": out.stderr[-1500:] if out.returncode else "",
    }


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--part", required=True, help="name of this backend's part of the JSON, e.g. gpu or cpu")
    p.add_argument("--cpu", action="store_true", help="run on the CPU (JAX_PLATFORMS=cpu), for a baseline")
    p.add_argument("--quick", action="store_true", help="fewer batch sizes and population sizes")
    p.add_argument("--fused-sizes", type=int, nargs="+", default=None, help="population sizes of the fused loop")
    p.add_argument("--smoke", action="store_true", help="tiny sizes, to check the script itself")
    p.add_argument("--skip-main-job", action="store_true")
    p.add_argument("--main-job-only", action="store_true", help="time only the main job")
    p.add_argument("--main-job-timeout", type=float, default=240.0)
    p.add_argument("--output", type=Path, default=RESULTS / "gpu_throughput.json")
    return p.parse_args(argv)


def main(argv=None) -> dict:
    args = parse_args(argv)
    import_s = time.perf_counter() - T_START
    small = [1, 64, 512] if args.quick else [1, 64, 512, 4096]
    large = [1, 8] if args.quick else [1, 8, 32, 128]
    sizes = [1000, 5000] if args.quick else [1000, 5000, 50000]
    sizes = args.fused_sizes or sizes
    blocks = (4, 2) if args.smoke else (200, 40)
    if args.smoke:
        small, large, sizes = [1, 4], [1], [200]
    part: dict = {"device": device_record(), "import_jax_s": import_s}
    if not args.main_job_only:
        part["engine"] = {
            "cpu_preset": engine_rows("cpu", small, blocks[0], vmap_all=False),
            "paper_preset": engine_rows("paper", large, blocks[1], vmap_all=False),
            "paper_preset_vmap_all": engine_rows("paper", large, blocks[1], vmap_all=True),
        }
        part["fused_pmcabc"] = fused_rows(sizes, [6.0, 3.0, 1.5, 0.75], seed=1)
    part["main_job"] = {"skipped": True} if args.skip_main_job else guarded(main_job, args.main_job_timeout)
    payload = {}
    if args.output.exists():
        try:
            payload = json.loads(args.output.read_text())
        except json.JSONDecodeError:
            payload = {}
    payload.setdefault("parts", {})[args.part] = part
    path = write_result(args.output, payload, part=args.part, command=command_line(argv))
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
