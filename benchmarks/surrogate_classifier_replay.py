"""The surrogate's success classifier, replayed on the water calibrations' own runs.

Each saved water surrogate run records every GROMACS run in order (``record_theta``,
``record_status``, ``record_iteration``).  For every batch after the start, this fits the success
classifier to the runs made before it and predicts the batch's outcomes, for two classifiers:

- ``quadratic``: quadratic logistic regression alone (the library's classifier before the GP);
- ``library``: ``jaxabc.surrogate.sampling.fit_feasibility`` as it is now (a GP classifier once
  runs of both outcomes are known).

Reported per data set: log loss and Brier score of the predictions, and the share of runs that
succeeded among those given an even chance or better (the design's level,
``design.MIN_DESIGN_SUCCESS``) and among the rest.  The runs were placed by whichever design made
the record, so this scores the classifiers on the same points, not the designs.

Each record is a part of the result (``provenance_parts``, keyed by the record's stem), so a
rerun of one water calibration stales and reruns only its own replay; ``--record`` names the
records to replay (default: every saved one) and the others' entries are kept.

Usage::

    python -m benchmarks.surrogate_classifier_replay [--record water_xray_robust_surrogate ...]
"""

from __future__ import annotations

import argparse
import json
import time
import warnings
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks._common import process_seconds, relative, write_result
from jaxabc.surrogate import design, sampling

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"


def records() -> list[Path]:
    """The saved water surrogate records (``water_*_surrogate.npz``), sorted."""
    return sorted(RESULTS.glob("water_*_surrogate.npz"))


def _quadratic(x_train: np.ndarray, ok: np.ndarray, x: np.ndarray, size: int) -> np.ndarray:
    model = sampling.fit_feasibility(x_train, ok, size=size)
    return np.exp(np.asarray(sampling.quadratic_log_success(model, jnp.asarray(x))))


def _library(x_train: np.ndarray, ok: np.ndarray, x: np.ndarray, size: int) -> np.ndarray:
    return np.asarray(sampling.feasibility(sampling.fit_feasibility(x_train, ok, size=size), jnp.asarray(x)))


CLASSIFIERS = {"quadratic": _quadratic, "library": _library}


def scores(p: np.ndarray, ok: np.ndarray) -> dict:
    """Log loss (p clipped to [1e-3, 1 - 1e-3]), Brier score, success shares at the design level."""
    pc = np.clip(p, 1e-3, 1 - 1e-3)
    high = p >= design.MIN_DESIGN_SUCCESS
    return {
        "log_loss": float(-np.mean(np.where(ok, np.log(pc), np.log1p(-pc)))),
        "brier": float(np.mean((p - ok) ** 2)),
        "runs_at_or_above_level": int(high.sum()),
        "success_share_at_or_above_level": float(ok[high].mean()) if high.any() else None,
        "runs_below_level": int((~high).sum()),
        "success_share_below_level": float(ok[~high].mean()) if (~high).any() else None,
    }


def replay(path: Path) -> dict:
    """Score both classifiers on one saved run's batches."""
    rec = np.load(path, allow_pickle=False)
    meta = json.loads(str(rec["metadata"]))
    low, high = np.asarray(meta["prior"]["low"]), np.asarray(meta["prior"]["high"])
    x = (rec["record_theta"] - low) / (high - low)
    ok = rec["record_status"] == 0
    it = rec["record_iteration"]
    predicted: dict[str, list[np.ndarray]] = {name: [] for name in CLASSIFIERS}
    outcomes = []
    for k in range(1, int(it.max()) + 1):
        before, batch = it < k, it == k
        if not batch.any():
            continue
        for name, classify in CLASSIFIERS.items():
            # Padded to the record's size: one compilation per record, not per batch.
            predicted[name].append(classify(x[before], ok[before], x[batch], len(x)))
        outcomes.append(ok[batch])
    y = np.concatenate(outcomes) if outcomes else np.zeros(0, bool)
    return {
        "record": relative(path),
        "num_runs": len(ok),
        "num_failed": int((~ok).sum()),
        "num_replayed": len(y),
        "replayed_success_share": float(y.mean()) if len(y) else None,
        "classifiers": {name: scores(np.concatenate(p), y) for name, p in predicted.items() if p},
    }


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=(__doc__ or "").split("\n\n")[0])
    parser.add_argument(
        "--record", nargs="+", metavar="STEM", help="records to replay, by stem (default: every saved one)"
    )
    parser.add_argument("--output", type=Path, default=RESULTS / "surrogate_classifier_replay.json")
    args = parser.parse_args(argv)
    saved = {path.stem: path for path in records()}
    chosen = args.record or list(saved)
    missing = [stem for stem in chosen if stem not in saved]
    if missing or not chosen:
        parser.error(f"no saved record {missing or ''} under {relative(RESULTS)}; saved: {sorted(saved) or 'none'}")
    warnings.filterwarnings("ignore", module="sklearn")
    runs, seconds = {}, {}
    setup = process_seconds()  # imports: what a rerun of any one part pays too
    for stem in chosen:
        t0 = time.time()
        with jax.enable_x64(True):  # scoped: a caller's process keeps its precision
            runs[stem] = replay(saved[stem])
        seconds[stem] = time.time() - t0
    old = json.loads(args.output.read_text()) if args.output.exists() else {}
    # Entries replayed earlier stay, each with its own part's provenance; a record no longer
    # saved drops out.
    kept = {k: v for k, v in (old.get("runs") or {}).items() if k in saved and k not in runs}
    payload = {  # each part's machine is in its provenance
        "design_level": design.MIN_DESIGN_SUCCESS,
        "runs": dict(sorted({**kept, **runs}.items())),
    }
    for stem in chosen:  # one write per part, so that each part records its own record as input
        out = write_result(
            args.output, payload, part=stem, inputs=[saved[stem]], cost_s=round(setup + seconds[stem], 1)
        )
    print(json.dumps(runs, indent=1))
    print(f"wrote {relative(out)}")
    return payload


if __name__ == "__main__":
    main()
