"""Does the GP surrogate say so when it is wrong?  Four problems with exact posteriors, over seeds.

Each case runs ``jaxabc.run("surrogate", ...)`` (synthetic-likelihood mode, 1000 draws) at a fixed
simulation budget for several seeds and compares the posterior with the exact one:

- ``step`` (d = 1): ``x = +3 if theta > 0.5 else -3``, plus ``N(0, 0.1^2)``; prior U(-5, 5),
  ``x_obs = 3``.  Exact posterior U(0.5, 5) (the other branch has likelihood ratio e^-1800):
  mean 2.75, sd 1.299.  A GP with one length scale cannot follow the step.
- ``conjugate`` (d = 1): ``x = theta + N(0, 1)``, prior U(-10, 10), ``x_obs = 0.7``: exact N(0.7, 1).
  The reference for the MCSE's calibration: z = (mean - 0.7) / ``result.mcse()`` should have rms ~1.
- ``heteroscedastic`` (d = 1): ``x = theta + (0.1 + 0.3 theta) z``, prior U(0, 10), ``x_obs = 5``;
  exact by a 20 001-point grid.  Run with ``noise_model="auto"`` and ``"homoscedastic"``.
- ``banana`` (d = 2): ``x = (a, b + a^2) + (1, 0.3) z``, prior U(-5, 5)^2, ``x_obs = (0, 0.5)``;
  exact by an 801^2 grid.

Per run: whether the surrogate called itself validated (and the failure it named when not), the
posterior mean's error in exact sd, the sd ratio, z = error / reported MCSE, and the simulations
used.  The honesty figure is ``validated_but_wrong``: runs that said validated while some
parameter's mean lay more than 3 reported MCSE from the exact mean.  A run that says NOT VALIDATED
is honest whatever its numbers.

Usage::

    python -m benchmarks.surrogate_honesty                # every case, its default seeds
    python -m benchmarks.surrogate_honesty --cases step --seeds 0 1 2
    python -m benchmarks.surrogate_honesty --quick        # step and conjugate, seed 0
"""

from __future__ import annotations

import argparse
import time
import warnings
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxabc
from benchmarks._common import write_result

#: Simulation budget of every run.
BUDGET = 200
#: |error| / reported MCSE beyond which a validated run counts as wrong.
Z_LIMIT = 3.0


def _step(key, t):
    return jnp.where(t[..., :1] > 0.5, 3.0, -3.0) + 0.1 * jax.random.normal(key, (1,))


def _conjugate(key, t):
    return t + jax.random.normal(key, t.shape)


def _het_sd(t):
    return 0.1 + 0.3 * t


def _heteroscedastic(key, t):
    return t + _het_sd(t) * jax.random.normal(key, t.shape)


_BANANA_SD = np.array([1.0, 0.3])


def _banana(key, t):
    return jnp.stack([t[0], t[1] + t[0] ** 2]) + jnp.asarray(_BANANA_SD) * jax.random.normal(key, (2,))


def _exact_step() -> tuple[np.ndarray, np.ndarray]:
    return np.array([2.75]), np.array([4.5 / np.sqrt(12.0)])


def _exact_conjugate() -> tuple[np.ndarray, np.ndarray]:
    return np.array([0.7]), np.array([1.0])  # the U(-10, 10) truncation moves neither by 1e-15


def _exact_heteroscedastic() -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(0.0, 10.0, 20001)
    lp = -0.5 * ((5.0 - g) / _het_sd(g)) ** 2 - np.log(_het_sd(g))
    p = np.exp(lp - lp.max())
    p /= p.sum()
    m = p @ g
    return np.array([m]), np.array([np.sqrt(p @ (g - m) ** 2)])


def _exact_banana() -> tuple[np.ndarray, np.ndarray]:
    g = np.linspace(-5.0, 5.0, 801)
    a, b = np.meshgrid(g, g, indexing="ij")
    lp = -0.5 * (a / _BANANA_SD[0]) ** 2 - 0.5 * ((0.5 - b - a**2) / _BANANA_SD[1]) ** 2
    p = np.exp(lp - lp.max())
    p /= p.sum()
    m = np.array([(p * a).sum(), (p * b).sum()])
    return m, np.sqrt([(p * (a - m[0]) ** 2).sum(), (p * (b - m[1]) ** 2).sum()])


#: name -> (simulator, prior bounds, observation, exact posterior, default seeds, noise models)
CASES: dict[str, tuple[Callable, tuple[list, list], list, Callable, list[int], tuple[str, ...]]] = {
    "step": (_step, ([-5.0], [5.0]), [3.0], _exact_step, list(range(5)), ("auto",)),
    "conjugate": (_conjugate, ([-10.0], [10.0]), [0.7], _exact_conjugate, list(range(10)), ("auto",)),
    "heteroscedastic": (
        _heteroscedastic,
        ([0.0], [10.0]),
        [5.0],
        _exact_heteroscedastic,
        list(range(3)),
        ("auto", "homoscedastic"),
    ),
    "banana": (_banana, ([-5.0, -5.0], [5.0, 5.0]), [0.0, 0.5], _exact_banana, list(range(5)), ("auto",)),
}


def run_one(case: str, seed: int, noise_model: str) -> dict[str, Any]:
    """One surrogate run of ``case`` at ``seed``; its posterior against the exact one."""
    simulate, (low, high), obs, exact, _, _ = CASES[case]
    prior = jaxabc.Uniform(low, high, names=tuple(f"t{i}" for i in range(len(low))))
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        r = jaxabc.run(
            "surrogate",
            simulate,
            prior,
            np.array(obs),
            max_simulations=BUDGET,
            num_particles=1000,
            seed=seed,
            noise_model=noise_model,
        )
    seconds = time.perf_counter() - t0
    em, esd = exact()
    w = np.asarray(r.weights)
    x = np.asarray(r.particles)
    mean = w @ x
    sd = np.sqrt(w @ (x - mean) ** 2)
    mcse = np.asarray(r.mcse(), dtype=float)
    d = r.diagnostics
    z = (mean - em) / mcse
    validated = bool(d.get("validated"))
    return {
        "case": case,
        "seed": seed,
        "noise_model": noise_model,
        "validated": validated,
        "failure": d.get("failure") or None,
        "stop_reason": r.stop_reason,
        "simulations": int(r.num_simulations),
        "mean": mean.tolist(),
        "sd": sd.tolist(),
        "exact_mean": em.tolist(),
        "exact_sd": esd.tolist(),
        "error_in_exact_sd": ((mean - em) / esd).tolist(),
        "sd_ratio": (sd / esd).tolist(),
        "mcse": mcse.tolist(),
        "mcse_sampling": np.asarray(d.get("mcse_sampling", np.nan)).tolist(),
        "mcse_emulator": np.asarray(d.get("mcse_emulator", np.nan)).tolist(),
        "z": z.tolist(),
        "wrong": bool(np.max(np.abs(z)) > Z_LIMIT),
        "seconds": round(seconds, 1),
    }


def summarise(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """Per (case, noise model): counts, rms z over the validated runs, the validated-but-wrong count."""
    out: dict[str, Any] = {}
    for key in sorted({(r["case"], r["noise_model"]) for r in runs}):
        rows = [r for r in runs if (r["case"], r["noise_model"]) == key]
        ok = [r for r in rows if r["validated"]]
        zs = np.array([v for r in ok for v in r["z"]])
        errs = np.array([abs(v) for r in rows for v in r["error_in_exact_sd"]])
        out[f"{key[0]}/{key[1]}"] = {
            "runs": len(rows),
            "validated": len(ok),
            "validated_but_wrong": sum(r["wrong"] for r in ok),
            "rms_z_validated": float(np.sqrt(np.mean(zs**2))) if zs.size else None,
            "max_abs_z_validated": float(np.max(np.abs(zs))) if zs.size else None,
            "max_abs_error_in_exact_sd": float(errs.max()),
            "sd_ratio_range": [
                float(min(min(r["sd_ratio"]) for r in rows)),
                float(max(max(r["sd_ratio"]) for r in rows)),
            ],
            "seconds_mean": float(np.mean([r["seconds"] for r in rows])),
        }
    return out


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cases", nargs="+", choices=sorted(CASES), default=list(CASES))
    parser.add_argument("--seeds", nargs="+", type=int, help="the same seeds for every case (default: each case's)")
    parser.add_argument("--quick", action="store_true", help="step and conjugate, seed 0, under results/quick")
    args = parser.parse_args(argv)
    cases = ["step", "conjugate"] if args.quick else args.cases
    runs = []
    for case in cases:
        seeds = [0] if args.quick else (args.seeds or CASES[case][4])
        for model in CASES[case][5]:
            for seed in seeds:
                row = run_one(case, seed, model)
                runs.append(row)
                print(
                    f"{case:16s} {model:13s} seed {seed}: validated={row['validated']} "
                    f"err/sd={np.round(row['error_in_exact_sd'], 2).tolist()} z={np.round(row['z'], 2).tolist()} "
                    f"sims={row['simulations']} {row['seconds']:.0f} s",
                    flush=True,
                )
    out = {
        "description": __doc__.split("\n\n")[0],
        "budget": BUDGET,
        "z_limit": Z_LIMIT,
        "summary": summarise(runs),
        "runs": runs,
    }
    print(f"wrote {write_result('surrogate_honesty', out, quick=args.quick)}")


if __name__ == "__main__":
    main()
