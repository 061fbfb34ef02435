"""Our water posteriors on the paper's statistics, sample to sample against the paper's own.

Dutta et al. (2018) published the final APMCABC generation of each TIP4P calibration (100
weighted particles; ``md.water.datasets.published_posterior``).  For every saved posterior of the
``paper`` statistics (the surrogate's ABC mode on the paper's unscaled distance, the paper's own
target, and the synthetic-likelihood mode, a different target), this compares, per dataset:

- weighted means, sds and the sigma-epsilon correlation, with each sample's effective size;
- the mean difference in units of the paper's posterior sd, and the sd ratio;
- the energy distance between the two weighted samples after scaling each parameter by the
  paper's sd, beside its null distribution: the same distance when the paper's 100 particles
  are replaced by 100 draws from our posterior carrying the paper's weights (its effective
  size).  A distance inside that spread is within what the paper's sample can resolve;
- the density of liquid water (298 K, 1 bar, quick preset, ``--seeds`` runs) at the paper's
  estimate, at ours and at TIP4P, beside the paper's Table 2 (5 ns runs): does the paper's
  predicted density follow from its estimate?

Usage (from the repository root)::

    python -m benchmarks.water_paper_samples --seeds 3 --workers 2
    python -m benchmarks.water_paper_samples --quick     # X-ray only, one density run per point
"""

from __future__ import annotations

import argparse
import concurrent.futures
import json
import multiprocessing
import time

import numpy as np

import jaxabc
from benchmarks._common import RESULTS, command_line, write_result
from md.water import datasets
from md.water.models import PAPER_TIP4P_ESTIMATES

#: The paper's Table 2: density of liquid water at 298 K (kg/m3) simulated at each estimate.
PAPER_TABLE2_DENSITY = {"TIP4P": 988.0, "neutron": 958.0, "xray": 854.0, "experiment": 997.0}
#: TIP4P's own (sigma_OO nm, epsilon_OO kJ/mol).
TIP4P_THETA = (0.315365, 0.64852)
#: Saved posteriors compared, by file suffix: (label, whether it targets the paper's posterior).
POSTERIORS = {
    "_surrogate_abc": ("GP surrogate, ABC on the paper's distance", True),
    "_surrogate": ("GP surrogate, synthetic likelihood", False),
}
NULL_DRAWS = 400


def weighted_moments(x: np.ndarray, w: np.ndarray) -> dict:
    """Weighted mean, sd (per column), correlation of the two columns, and Kish's effective size."""
    w = w / w.sum()
    mean = w @ x
    cov = (x - mean).T @ ((x - mean) * w[:, None]) / (1.0 - w @ w)
    sd = np.sqrt(np.diag(cov))
    return {
        "mean": mean.tolist(),
        "sd": sd.tolist(),
        "correlation": float(cov[0, 1] / (sd[0] * sd[1])),
        "ess": float(1.0 / np.sum(w**2)),
        "draws": len(w),
    }


def _mean_distance(x: np.ndarray, wx: np.ndarray, y: np.ndarray, wy: np.ndarray) -> float:
    d = np.sqrt(((x[:, None, :] - y[None, :, :]) ** 2).sum(-1))
    return float(wx @ d @ wy)


def energy_distance(x: np.ndarray, wx: np.ndarray, y: np.ndarray, wy: np.ndarray) -> float:
    """Energy distance between two weighted samples (V-statistic: 0 for identical samples)."""
    wx, wy = wx / wx.sum(), wy / wy.sum()
    return 2 * _mean_distance(x, wx, y, wy) - _mean_distance(x, wx, x, wx) - _mean_distance(y, wy, y, wy)


def null_energy_distance(x: np.ndarray, w: np.ndarray, paper_w: np.ndarray, rng: np.random.Generator) -> dict:
    """Energy distances between our weighted sample ``(x, w)`` and ``len(paper_w)`` draws from it
    that carry the paper's weights (shuffled): the distance if the paper's sample were drawn from
    our posterior, with its own effective size.  ``x`` already scaled."""
    w = w / w.sum()
    within = _mean_distance(x, w, x, w)
    n = len(paper_w)
    values = []
    for _ in range(NULL_DRAWS):
        y, wy = x[rng.choice(len(x), n, p=w)], rng.permutation(paper_w) / paper_w.sum()
        values.append(2 * _mean_distance(x, w, y, wy) - within - _mean_distance(y, wy, y, wy))
    return {"median": float(np.median(values)), "q95": float(np.quantile(values, 0.95)), "num": NULL_DRAWS}


def compare(kind: str, rng: np.random.Generator) -> dict:
    """Every saved ``paper``-statistics posterior of ``kind`` against the paper's final generation."""
    published = datasets.published_posterior(kind)
    px, pw = published[:, :2], published[:, 2]
    paper = weighted_moments(px, pw)
    scale = np.asarray(paper["sd"])
    entry: dict = {
        "paper": paper,
        "paper_bayes_estimate": PAPER_TIP4P_ESTIMATES[kind]["bayes_estimate"],
        "ours": {},
    }
    for suffix, (label, same_target) in POSTERIORS.items():
        path = RESULTS / f"water_{kind}_paper{suffix}.npz"
        if not path.is_file():
            continue
        result = jaxabc.load(path)
        saved = RESULTS / f"water_{kind}{suffix}.json"
        run = (json.loads(saved.read_text()).get("paper") or {}) if saved.is_file() else {}
        x = np.asarray(result.particles, np.float64)[:, :2]
        w = np.asarray(result.weights, np.float64)
        ours = weighted_moments(x, w)
        ours |= {
            "label": label,
            "paper_target": same_target,
            "file": path.relative_to(RESULTS.parent.parent).as_posix(),
            "run_file": saved.relative_to(RESULTS.parent.parent).as_posix() if saved.is_file() else None,
            "bayes_estimate": np.asarray(result.bayes_estimate(), np.float64)[:2].tolist(),
            # The run's own verdicts: a posterior whose emulator failed validation, or under which
            # no parameter reproduces the data, says so beside the comparison.
            "validated": (run.get("surrogate") or {}).get("validated"),
            "misfit_p_value": ((run.get("surrogate") or {}).get("observed_misfit") or {}).get("p_value"),
            "mean_difference_in_paper_sd": ((np.asarray(ours["mean"]) - paper["mean"]) / scale).tolist(),
            "sd_ratio": (np.asarray(ours["sd"]) / scale).tolist(),
            "energy_distance": energy_distance(x / scale, w, px / scale, pw),
            "null_energy_distance": null_energy_distance(x / scale, w, pw, rng),
        }
        ours["within_null_q95"] = bool(ours["energy_distance"] <= ours["null_energy_distance"]["q95"])
        entry["ours"][suffix.lstrip("_")] = ours
    return entry


def _density(task: tuple) -> tuple[str, str, int, float | None, str]:
    """Worker: one quick-preset NPT run at 298 K, its density or the failure's reason."""
    kind, label, theta, seed = task
    from jaxabc.errors import SimulationFailure
    from md.water.model_simulator import WaterModelSimulator
    from md.water.models import MODELS

    simulate = WaterModelSimulator(MODELS["TIP4P"], "quick", "paper", kind)
    try:
        out = simulate.run(np.array([0, 500 + seed], np.uint32), np.asarray(theta, np.float64))
        return kind, label, seed, float(out.density_kg_m3), ""
    except SimulationFailure as failure:
        return kind, label, seed, None, str(failure)


def densities(points: dict[str, dict[str, list[float]]], seeds: int, workers: int) -> dict:
    """Density mean and standard error over ``seeds`` runs at each (kind, label) point."""
    tasks = [
        (kind, label, theta, s) for kind, pts in points.items() for label, theta in pts.items() for s in range(seeds)
    ]
    context = multiprocessing.get_context("spawn")
    with concurrent.futures.ProcessPoolExecutor(workers, mp_context=context) as pool:
        runs = list(pool.map(_density, tasks))
    out: dict = {}
    for kind, pts in points.items():
        out[kind] = {}
        for label, theta in pts.items():
            vals = [d for k, lab, _, d, _ in runs if k == kind and lab == label and d is not None]
            fails = [r for k, lab, _, d, r in runs if k == kind and lab == label and d is None]
            out[kind][label] = {
                "theta": list(theta),
                "density_kg_m3": float(np.mean(vals)) if vals else None,
                "standard_error": float(np.std(vals, ddof=1) / np.sqrt(len(vals))) if len(vals) > 1 else None,
                "runs": len(vals),
                "failures": fails,
            }
    return out


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    p.add_argument("--seeds", type=int, default=3, help="density runs per point")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--quick", action="store_true", help="X-ray only, one density run per point")
    args = p.parse_args(argv)
    if args.seeds < 1:
        raise SystemExit(f"--seeds must be at least 1, got {args.seeds}")
    kinds = ("xray",) if args.quick else ("simulated", "xray", "neutron")
    seeds = 1 if args.quick else args.seeds
    start = time.perf_counter()
    rng = np.random.default_rng(0)
    samples = {kind: compare(kind, rng) for kind in kinds}
    points: dict[str, dict[str, list[float]]] = {}
    for kind in kinds:
        if kind == "simulated":
            continue  # no Table 2 column
        points[kind] = {"paper estimate": list(PAPER_TIP4P_ESTIMATES[kind]["bayes_estimate"])}
        for name, ours in samples[kind]["ours"].items():
            if ours["paper_target"]:
                points[kind][f"our estimate ({name})"] = ours["bayes_estimate"]
    points.setdefault("xray", {})["TIP4P"] = list(TIP4P_THETA)
    payload = {
        "samples": samples,
        "density": densities(points, seeds, args.workers),
        "paper_table2_density_kg_m3": PAPER_TABLE2_DENSITY,
        "density_protocol": "WaterModelSimulator('TIP4P', 'quick'): 216 molecules, 20 ps NPT at 298 K and 1 bar, "
        "analysis 5-20 ps; the paper's Table 2 used 5 ns runs",
        "seeds": seeds,
        "wall_time_s": time.perf_counter() - start,
    }
    inputs = [datasets.DATA_DIR / f"dutta2018_abcpy-models_posterior_{k}_final_generation.csv" for k in kinds]
    inputs += [
        RESULTS.parent.parent / o[key]
        for k in kinds
        for o in samples[k]["ours"].values()
        for key in ("file", "run_file")
        if o[key]
    ]
    path = write_result("water_paper_samples", payload, quick=args.quick, inputs=inputs, command=command_line(argv))
    print(f"wrote {path}")
    return payload


if __name__ == "__main__":
    main()
