"""Throughput of the jax-md helium engine (batched) against LAMMPS, in the same run.

For each helium set-up (the 1000-atom ``paper`` system and the small ``cpu`` preset) this times

- jax-md: one compiled, batched segment of MD steps for batch sizes 1, 8, 32, 128 (the second
  call, after compilation), NPT with the preset's neighbour strategy and batching
  (``vmap_width``: the paper system maps over members one by one, the CPU preset vmaps);
- LAMMPS (Debian ``lmp``, one MPI rank, one thread): the same system, same steps.

and writes atom-steps per second, system-steps per second, and both per core to
``benchmarks/results/engine_throughput.json``.  jax-md uses every core XLA gives it (2 here);
LAMMPS one.  The machine is shared, so numbers carry the noise of whatever else runs.

Run: ``nice -n 5 python -m benchmarks.engine_throughput [--quick]``.

``--small-system`` (implies ``--single-core``'s one XLA thread) times the 32-atom ``cpu``
preset, batched over parameters, against LAMMPS on the same system, in system-steps per
CPU-second (``time.process_time``; LAMMPS: loop time x its "% CPU use"), so the ratios hold on a
machine shared with other work.  With ``--baseline-tree DIR`` (a checkout of an earlier commit)
the same engine timing and the main job ``jaxabc example helium`` (wall and CPU seconds of the
child process, the jobs one at a time before the rest) run for both trees in the same run,
giving the speed-ups over that commit.  It writes
``engine_throughput_small_system.json``.

``--single-core`` pins this process (and the LAMMPS it starts) to core 0 and XLA to one thread,
so both engines are timed on the same single core, the way a process pool with one simulation
process per core would use a machine; it writes ``engine_throughput_single_core.json``.  Rates
there are per *CPU* second (jax-md: ``time.process_time`` of this single-threaded process;
LAMMPS: its loop time times its reported "% CPU use"), so the ratio does not depend on what
else shares the core; wall-clock rates are kept alongside.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import time
from importlib import metadata
from pathlib import Path

SMALL_SYSTEM = "--small-system" in sys.argv
RATES_ONLY = "--rates-only" in sys.argv
SINGLE_CORE = "--single-core" in sys.argv or SMALL_SYSTEM
USER_ENV = dict(os.environ)  # the main job runs as a user runs it, without the flags below
if SINGLE_CORE:
    # Before JAX is imported: one XLA thread, and this process plus its children on core 0.
    os.environ["XLA_FLAGS"] = (
        os.environ.get("XLA_FLAGS", "") + " --xla_cpu_multi_thread_eigen=false intra_op_parallelism_threads=1"
    )
    if not SMALL_SYSTEM:
        os.sched_setaffinity(0, {0})

import jax  # noqa: E402
import numpy as np  # noqa: E402

from benchmarks._common import write_result  # noqa: E402
from benchmarks._engine_timing import time_jax_md  # noqa: E402
from md import helium, lammps_reference  # noqa: E402

RESULTS = (
    Path(__file__).resolve().parent
    / "results"
    / (
        "engine_throughput_small_system.json"
        if SMALL_SYSTEM
        else "engine_throughput_single_core.json"
        if SINGLE_CORE
        else "engine_throughput.json"
    )
)


def versions() -> dict:
    """Versions of everything timed here (LAMMPS: the first line of ``lmp -h``)."""
    out = {"python": platform.python_version()}
    for name in ("jax", "jaxlib", "jax-md", "numpy"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    try:
        head = subprocess.run(["lmp", "-h"], capture_output=True, text=True, timeout=30).stdout
        out["lammps"] = next((line.strip() for line in head.splitlines() if line.strip()), None)
    except (OSError, subprocess.TimeoutExpired):
        out["lammps"] = None
    return out


def neighbour_strategy(preset: helium.HeliumPreset) -> dict:
    """How the jax-md engine of a preset finds pairs (recorded with every timing)."""
    engine = helium.make_engine(preset)
    out = {
        "use_neighbor_list": preset.use_neighbor_list,
        "rebuild_every": preset.rebuild_every,
        "rebuild": preset.rebuild,
    }
    if engine.neighbor_template is not None:
        spec = engine.neighbor_template.spec
        out.update(
            skin_nm=preset.skin_nm,
            format=spec.format,
            cells_per_side=spec.cells_per_side,
            pair_capacity=spec.capacity,
            candidate_capacity=spec.candidate_capacity,
            cell_capacity=spec.cell_capacity,
        )
    return out


def time_lammps(preset: helium.HeliumPreset, steps: int) -> dict:
    """Wall time of one LAMMPS run of ``steps`` NPT steps (startup included, thermo sparse)."""
    every = steps // 10
    p = helium.get_preset(
        preset,
        equilibration_ps=0.0,
        sample_every_ps=every * preset.dt_ps,
        production_ps=steps * preset.dt_ps,
    )
    run = lammps_reference.run_helium(jax.random.PRNGKey(0), helium.TRUE_THETA, p)
    # LAMMPS's own loop time: its start-up (reading, neighbour set-up) would otherwise be charged
    # to the steps, which flattered jax-md by up to 2x in an earlier version of this benchmark.
    seconds = run.loop_cpu_seconds if SINGLE_CORE else run.loop_seconds
    return {
        "engine": "lammps",
        "batch": 1,
        "steps": run.steps,
        "seconds": seconds,
        "measure": "cpu" if SINGLE_CORE else "wall",
        "loop_seconds": run.loop_seconds,
        "loop_cpu_seconds": run.loop_cpu_seconds,
        "wall_seconds_including_startup": run.wall_seconds,
        "system_steps_per_second": run.steps / seconds,
        "atom_steps_per_second": run.steps * preset.num_atoms / seconds,
        "atom_steps_per_second_per_core": run.steps * preset.num_atoms / seconds,
        "cores": 1,
    }


def per_simulation(preset: helium.HeliumPreset, batch: int = 64, repeats: int = 3) -> dict:
    """Wall seconds per complete ABC simulation (equilibration + production + f_B).

    jax-md: ``simulate_batch`` of ``batch`` members (compiled), divided by ``batch``, times the
    cores it used.  LAMMPS: complete runs including process start-up and file I/O, which is
    what an external simulator costs per particle.
    """
    simulate_batch = helium.make_batch_simulator(preset, batch_size=batch)
    keys = jax.random.split(jax.random.PRNGKey(1), batch)
    thetas = np.tile(np.asarray(helium.TRUE_THETA, np.float32), (batch, 1))
    simulate_batch(keys, thetas)  # compile
    t0 = time.perf_counter()
    simulate_batch(jax.random.split(jax.random.PRNGKey(2), batch), thetas)
    jax_seconds = (time.perf_counter() - t0) / batch
    lmp = []
    if lammps_reference.lammps_available():
        for k in jax.random.split(jax.random.PRNGKey(3), repeats):
            t0 = time.perf_counter()
            lammps_reference.run_helium(k, helium.TRUE_THETA, preset)
            lmp.append(time.perf_counter() - t0)
    cores = os.cpu_count() or 1
    return {
        "setup": preset.name,
        "jax_md_batch": batch,
        "jax_md_wall_seconds_per_simulation": jax_seconds,
        "jax_md_core_seconds_per_simulation": jax_seconds * cores,
        "lammps_wall_seconds_per_simulation": float(np.mean(lmp)) if lmp else None,
        "lammps_core_seconds_per_simulation": float(np.mean(lmp)) if lmp else None,
    }


def small_system_rates(batches: tuple[int, ...], num_blocks: int) -> list[dict]:
    """jax-md system-steps per CPU-second of the ``cpu`` preset at each batch size."""
    preset = helium.get_preset("cpu")
    return [time_jax_md(preset, b, num_blocks, single_core=SINGLE_CORE) for b in batches]


def _in_tree(tree: Path, args: list[str], timeout: float = 3600) -> str:
    """Stdout of ``python args`` run with ``tree`` first on the path."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    return subprocess.run(
        [sys.executable, *args], env=env, cwd=tree, capture_output=True, text=True, timeout=timeout, check=True
    ).stdout


def main_job_seconds(trees: dict[str, Path]) -> dict:
    """Wall and CPU seconds of ``jaxabc example helium`` (the main job) run from each tree.

    Each tree runs it twice with its own empty compilation cache (``JAXABC_COMPILATION_CACHE``
    set to a fresh folder): ``cold`` compiles everything, as on a fresh machine after
    ``scripts/setup.sh`` (which builds the C++ force kernel); ``warm`` is the next run, which
    loads the programs the main job cached (a tree whose job caches nothing compiles again).
    The jobs run one at a time, before anything else in this benchmark, so that their wall
    times compare; each record keeps the load average at its start, to show whether something
    else shared the machine.  Returns ``{tree: {"cold": {...}, "warm": {...}}}``.
    """
    import tempfile

    out: dict[str, dict] = {name: {} for name in trees}
    for run in ("cold", "warm"):
        for name, tree in trees.items():
            folder = tempfile.mkdtemp(prefix=f"main_job_{name}_") if run == "cold" else out[name]["_folder"]
            out[name]["_folder"] = folder
            code = (
                "import sys; from jaxabc.cli import main; "
                f"sys.exit(main(['example', 'helium', '--output', {folder + '/run'!r}]))"
            )
            env = dict(USER_ENV, PYTHONPATH=str(tree), JAXABC_COMPILATION_CACHE=folder + "/xla")
            load = os.getloadavg()[0]
            start = time.perf_counter()
            proc = subprocess.Popen(
                [sys.executable, "-c", code], cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL
            )
            _, status, usage = os.wait4(proc.pid, 0)
            out[name][run] = {
                "tree": str(tree),
                "exit_status": status,
                "wall_seconds": time.perf_counter() - start,
                "cpu_seconds": usage.ru_utime + usage.ru_stime,
                "load_average_1min_at_start": load,
            }
            print(f"main job {name} {run}: {out[name][run]}", flush=True)
    for name in trees:
        shutil.rmtree(out[name].pop("_folder"), ignore_errors=True)
    return out


def small_system(args: argparse.Namespace) -> None:
    """The small-system comparison (see the module notes)."""
    batches, blocks = (64, 256), 400
    if RATES_ONLY:
        print(json.dumps(small_system_rates(batches, blocks)))
        return
    here = Path(__file__).resolve().parent.parent
    trees = {"this": here}
    if args.baseline_tree is not None:
        trees["baseline"] = args.baseline_tree.resolve()
    jobs = main_job_seconds(trees) if args.main_job else {}
    preset = helium.get_preset("cpu")
    lmp = time_lammps(preset, 250_000) if lammps_reference.lammps_available() else None
    script = str(Path(__file__).resolve())
    rates = {}
    for name, tree in trees.items():
        out = _in_tree(tree, [script, "--small-system", "--rates-only"])
        rates[name] = json.loads(out.strip().splitlines()[-1])
        for r in rates[name]:
            r["ratio_to_lammps_same_run"] = (
                r["system_steps_per_second"] / lmp["system_steps_per_second"] if lmp else None
            )
            print(
                f"{name:9s} b={r['batch']:<4d} {r['system_steps_per_second']:10.0f} "
                f"system-steps/CPU-s  ({r['ratio_to_lammps_same_run'] or float('nan'):.2f} x "
                "LAMMPS)",
                flush=True,
            )
    ratios = {}
    if "baseline" in rates:
        ratios["engine_speedup_over_baseline"] = {
            str(a["batch"]): a["system_steps_per_second"] / b["system_steps_per_second"]
            for a, b in zip(rates["this"], rates["baseline"], strict=True)
        }
    if "baseline" in jobs:
        for run in ("cold", "warm"):
            base, this = jobs["baseline"][run], jobs["this"][run]
            ratios[f"main_job_{run}_cpu_speedup_over_baseline"] = base["cpu_seconds"] / this["cpu_seconds"]
            ratios[f"main_job_{run}_wall_speedup_over_baseline"] = base["wall_seconds"] / this["wall_seconds"]
    if lmp:
        ratios["best_ratio_to_lammps"] = max(r["ratio_to_lammps_same_run"] for r in rates["this"])
    # Through the shared helper, so that the result records its commit and fingerprint.
    write_result(
        args.output,
        {
            "description": __doc__,
            "command": " ".join([os.path.basename(sys.executable), *sys.argv]),
            "measure": "CPU seconds (process_time; LAMMPS loop time x % CPU): the machine is shared",
            "versions": versions(),
            "machine": {
                "cpus": os.cpu_count(),
                "platform": platform.platform(),
                "processor": platform.processor(),
                "jax": jax.__version__,
                "load_average_at_end": os.getloadavg(),
            },
            "lammps": lmp,
            "jax_md": rates,
            "main_job": jobs,
            "ratios": ratios,
        },
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="batch sizes 1 and 8 only")
    parser.add_argument("--output", type=Path, default=RESULTS)
    parser.add_argument(
        "--single-core", action="store_true", help="both engines on core 0, XLA single-threaded (see the module notes)"
    )
    parser.add_argument(
        "--per-simulation-only",
        action="store_true",
        help="only (re)measure the per-simulation comparison, keep the rest",
    )
    parser.add_argument(
        "--small-system", action="store_true", help="the 32-atom cpu preset against LAMMPS (see the module notes)"
    )
    parser.add_argument("--rates-only", action="store_true", help=argparse.SUPPRESS)
    parser.add_argument(
        "--baseline-tree", type=Path, default=None, help="with --small-system: also time this checkout, same run"
    )
    parser.add_argument(
        "--main-job", action="store_true", help="with --small-system: also time `jaxabc example helium`"
    )
    args = parser.parse_args()
    if SMALL_SYSTEM:
        small_system(args)
        return
    if args.per_simulation_only:
        data = json.loads(args.output.read_text())
        data["per_simulation"] = per_simulation(helium.get_preset("cpu"))
        print(data["per_simulation"], flush=True)
        write_result(args.output, data)
        return
    batches = (1, 8) if args.quick else (1, 8, 32, 128)
    setups = {
        # The published system, with a cell-list neighbour list.
        "paper_1000_atoms_1atm": (helium.get_preset("paper"), 400, 20_000),
        # The CPU preset (all pairs, cached-virial NPT).
        "cpu_preset": (helium.get_preset("cpu"), 500, 50_000),
    }
    records = []
    for name, (preset, steps, lammps_steps) in setups.items():
        blocks = steps // preset.rebuild_every
        if SINGLE_CORE:
            # Longer runs: LAMMPS's time includes its start-up, which must not decide the ratio.
            blocks, lammps_steps = 5 * blocks, 5 * lammps_steps
        lmp = time_lammps(preset, lammps_steps) if lammps_reference.lammps_available() else None
        if lmp:
            lmp["setup"] = name
            records.append(lmp)
            print(f"{name:24s} lammps      {lmp['atom_steps_per_second_per_core']:12.3e} atom-steps/s/core", flush=True)
        for b in batches:
            if preset.num_atoms * b > 64_000 and b > 32:
                blocks_b = max(2, blocks // 4)
            else:
                blocks_b = blocks
            r = time_jax_md(preset, b, blocks_b, single_core=SINGLE_CORE)
            r["setup"] = name
            r["num_atoms"] = preset.num_atoms
            r["neighbours"] = neighbour_strategy(preset)
            ratio = r["atom_steps_per_second_per_core"] / lmp["atom_steps_per_second_per_core"] if lmp else float("nan")
            r["ratio_to_lammps_per_core_same_run"] = ratio if lmp else None
            records.append(r)
            print(
                f"{name:24s} jax-md b={b:<4d}{r['atom_steps_per_second_per_core']:12.3e} "
                f"atom-steps/s/core  ({ratio:.2f} x LAMMPS per core)",
                flush=True,
            )
    write_result(
        args.output,
        {
            "description": __doc__,
            "versions": versions(),
            "single_core": SINGLE_CORE,
            "records": records,
            "per_simulation": None if SINGLE_CORE else per_simulation(helium.get_preset("cpu")),
        },
    )


if __name__ == "__main__":
    main()
