"""Paper-preset check of the preferred water model of the model choice (issue 17).

The model choice (``benchmarks/water_model_choice.py``) calibrates every model in the quick
preset (216 molecules, 20 ps).  This asks whether the preferred model's calibration holds in the
paper's preset (515 molecules, 100 ps): ``--runs`` posterior draws run in *both* presets with the
same keys, plus ``--published-runs`` runs at the model's published parameters in the paper preset.
For every joint summary it reports the measured value, each set's mean and spread, the preset
shift (paper - quick, paired over the draws, with its standard error) and the standardised
residual of the data against each set (spread and stated measurement error combined).

Every run is cached under ``--cache-dir`` (keyed by model, preset, key and parameters), so
rerunning the command after an interruption replays the finished runs and continues.

Usage::

    python -m benchmarks.water_model_paper_check --data xray --workers 2    # ~15 min on 2 cores
    python -m benchmarks.water_model_paper_check --tiny                     # plumbing smoke test

``--tiny`` runs 2 ps simulations in the quick preset only, from the tiny model choice's result;
its numbers mean nothing.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import jax
import numpy as np

import jaxabc
from benchmarks._common import QUICK_RESULTS, RESULTS, RUNS, command_line, model_selection_record, write_result
from benchmarks._water_model_choice_paths import model_choice_folder, physical_marginal
from jaxabc.model_choice import load_model_choice
from md.water.joint_data import JOINT_DATA_FILE, joint_observed, joint_record
from md.water.model_simulator import CachedSummaries, WaterModelSimulator
from md.water.models import get_model

ROOT = Path(__file__).resolve().parents[1]


def parse_args(argv=None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--data", choices=("xray", "neutron"), default="xray")
    p.add_argument("--model", default=None, help="default: the most probable model of the model choice")
    p.add_argument("--model-choice", type=Path, default=None, help="saved model-choice folder")
    p.add_argument("--runs", type=int, default=8, help="posterior draws, each run in both presets")
    p.add_argument("--published-runs", type=int, default=4, help="paper-preset runs at the published parameters")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--cache-dir", type=Path, default=None)
    p.add_argument("--name", default="water_model_paper_check", help="result name: <name>.json (one per model)")
    p.add_argument("--tiny", action="store_true", help="smoke test: 2 ps quick-preset runs, quick JSON")
    args = p.parse_args(argv)
    suffix = f"{args.data}_quick" + ("_tiny" if args.tiny else "")
    # The folder the registry's model choice saved (its JSON records it), or the smoke test's.
    args.model_choice = args.model_choice or model_choice_folder(args.data, args.tiny)
    args.cache_dir = args.cache_dir or (
        RUNS / "water_model_paper_check" / suffix if args.tiny else RUNS / "cache" / "water_model_paper_check" / suffix
    )
    if args.tiny:
        args.runs, args.published_runs = 2, 1
    return args


def run_set(model: str, preset: str, overrides: dict, data: str, thetas: np.ndarray, key, executor, cache_dir: Path):
    """Joint summaries (n, 11) of ``thetas`` (NaN rows for failed runs) and the failure reasons."""
    simulator = WaterModelSimulator(model, preset, "robust", data, **overrides)
    simulate = CachedSummaries(simulator, np.ones(11, bool), cache_dir)
    keys = np.asarray(jax.random.key_data(jax.random.split(key, len(thetas))))
    batch = executor.map(simulate.full, keys, thetas)
    out = np.where((batch.status == 0)[:, None], batch.summaries, np.nan)
    return out, [r for r, s in zip(batch.reasons, batch.status, strict=True) if s != 0]


def describe(values: np.ndarray) -> dict:
    """Mean, sd and count of the finite rows, per summary."""
    good = values[np.all(np.isfinite(values), axis=1)]
    n = good.shape[0]
    return {
        "num_runs": n,
        "mean": good.mean(axis=0).tolist() if n else None,
        "sd": good.std(axis=0, ddof=1).tolist() if n > 1 else None,
    }


def residuals(observed: np.ndarray, errors: np.ndarray, stats: dict) -> list[float | None]:
    """(observed - mean) / sqrt(sd^2 + measurement sd^2) per summary; None where unmeasured."""
    if stats["mean"] is None or stats["sd"] is None:
        return [None] * len(observed)
    mean, sd = np.array(stats["mean"]), np.array(stats["sd"])
    scale = np.sqrt(sd**2 + np.where(np.isfinite(errors), errors, 0.0) ** 2)
    z = (observed - mean) / np.where(scale > 0, scale, np.nan)
    return [None if (o == 0.0 or not np.isfinite(v)) else float(v) for o, v in zip(observed, z, strict=True)]


def main(argv=None) -> dict:
    args = parse_args(argv)
    t0 = time.perf_counter()
    choice = load_model_choice(args.model_choice)
    name = args.model or choice.best
    model = get_model(name)
    data = joint_observed(args.data)
    posterior = physical_marginal(choice.posterior(name))  # the force field's parameters only
    draws = np.asarray(posterior.resample(args.runs, seed=args.seed), dtype=np.float64)
    published = np.tile(np.asarray(model.lj, dtype=np.float64), (args.published_runs, 1))
    key = jax.random.key(args.seed + 17)
    quick_overrides = {"num_steps": 1000, "analysis_start_ps": 0.4} if args.tiny else {}
    check_preset, check_overrides = ("quick", quick_overrides) if args.tiny else ("paper", {})
    timeout = WaterModelSimulator(name, check_preset, "robust", **check_overrides).protocol.timeout_s + 60
    executor = jaxabc.ProcessPoolExecutor(max_workers=args.workers, timeout=timeout)
    try:

        def runs(preset, overrides, thetas, k):
            return run_set(name, preset, overrides, args.data, thetas, k, executor, args.cache_dir)

        # Same keys in both presets: the shift is paired over the draws.
        quick, quick_fail = runs("quick", quick_overrides, draws, key)
        paper, paper_fail = runs(check_preset, check_overrides, draws, key)
        pub, pub_fail = runs(check_preset, check_overrides, published, jax.random.fold_in(key, 1))
    finally:
        executor.close()
    both = np.all(np.isfinite(quick), axis=1) & np.all(np.isfinite(paper), axis=1)
    diff = paper[both] - quick[both]
    n = int(both.sum())
    shift = {
        "num_pairs": n,
        "mean": diff.mean(axis=0).tolist() if n else None,
        "se": (diff.std(axis=0, ddof=1) / np.sqrt(n)).tolist() if n > 1 else None,
    }
    sets = {"calibrated_quick": describe(quick), "calibrated_paper": describe(paper), "published_paper": describe(pub)}
    payload = {
        "benchmark": args.name,
        "data": args.data,
        **model_selection_record(choice, name, bool(args.model), args.model_choice),
        "check_preset": check_preset + (" (tiny smoke: 2 ps runs, numbers meaningless)" if args.tiny else ""),
        "published_lj": list(model.lj),
        "posterior_draws": draws.tolist(),
        "summaries": {
            "names": list(data.names),
            "observed": data.observed.tolist(),
            "stated_errors": [None if not np.isfinite(e) else float(e) for e in data.errors],
            "fitted": [str(n) for n, f in zip(data.names, data.fitted, strict=True) if f],
            "held_out": [str(n) for n, h in zip(data.names, data.held_out, strict=True) if h],
        },
        "sets": sets,
        "failures": {"calibrated_quick": quick_fail, "calibrated_paper": paper_fail, "published_paper": pub_fail},
        "preset_shift": shift,
        "residuals": {k: residuals(data.observed, data.errors, v) for k, v in sets.items()},
        "data_record": joint_record(),
        "settings": {"runs": args.runs, "published_runs": args.published_runs, "seed": args.seed},
        "wall_time_s": time.perf_counter() - t0,
    }
    path = write_result(
        (QUICK_RESULTS if args.tiny else RESULTS) / f"{args.name}.json",
        payload,
        inputs=[JOINT_DATA_FILE, args.model_choice / "model_choice.json"],
        command=command_line(argv),
    )
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
