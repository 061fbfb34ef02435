"""benchmarks/surrogate_peers.py: exact posteriors, simulators, metrics, cache and page (no peer runs)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from benchmarks import surrogate_peers as sp

TWO_D = [n for n in sp.PROBLEM_NAMES if sp.PROBLEMS[n]["d"] == 2]


def _direct_moments(name: str, x: np.ndarray, n: int, seed: int) -> tuple[np.ndarray, np.ndarray]:
    draws = sp.exact_sample(name, x, n, np.random.default_rng(seed))
    return draws.mean(axis=0), np.cov(draws, rowvar=False)


@pytest.mark.parametrize("name", ["banana", "student", "linear"])
def test_the_grid_agrees_with_the_direct_exact_sampler(name: str) -> None:
    # Two routes to the same posterior: the likelihood on a grid, and sampling the model's noise.
    for seed in (0, 1):
        x = sp.instance(name, seed, exact_draws=10, moment_draws=10).observed
        mean_g, cov_g = sp.grid_moments(sp.grid_posterior(name, x))
        mean_d, cov_d = _direct_moments(name, x, 400_000, seed)
        sd_g, sd_d = np.sqrt(np.diag(cov_g)), np.sqrt(np.diag(cov_d))
        assert np.all(np.abs(mean_g - mean_d) < 0.01 * sd_g), (name, mean_g, mean_d)
        assert np.all(np.abs(sd_g / sd_d - 1) < 0.015), (name, sd_g, sd_d)


def _mvt_logpdf(y: np.ndarray, loc: np.ndarray, chol: np.ndarray, df: float) -> np.ndarray:
    d = len(loc)
    w = np.linalg.solve(chol, (y - loc).T).T
    q = np.sum(w**2, axis=1)
    const = math.lgamma((df + d) / 2) - math.lgamma(df / 2) - d / 2 * math.log(df * math.pi)
    return const - np.log(np.diag(chol)).sum() - (df + d) / 2 * np.log1p(q / df)


def _mvt_sample(rng: np.random.Generator, n: int, loc: np.ndarray, chol: np.ndarray, df: float) -> np.ndarray:
    z = rng.standard_normal((n, len(loc))) @ chol.T
    return loc + z / np.sqrt(rng.chisquare(df, n) / df)[:, None]


def _importance_moments(
    name: str, x: np.ndarray, loc: np.ndarray, cov: np.ndarray, df: float, n: int, rng: np.random.Generator
) -> tuple[np.ndarray, np.ndarray, float]:
    """Posterior mean, sds and ESS of the likelihood on the prior box, by importance sampling from
    a multivariate t (``loc``, scale ``cov``, ``df``)."""
    p = sp.PROBLEMS[name]
    chol = np.linalg.cholesky(cov)
    y = _mvt_sample(rng, n, loc, chol, df)
    inside = np.all((y >= np.array(p["low"])) & (y <= np.array(p["high"])), axis=1)
    logw = np.where(inside, sp.log_likelihood(name, y, x), -np.inf) - _mvt_logpdf(y, loc, chol, df)
    w = np.exp(logw - logw.max())
    w /= w.sum()
    mean = w @ y
    return mean, np.sqrt(w @ (y - mean) ** 2), float(1.0 / np.sum(w**2))


def test_the_heteroscedastic_grid_agrees_with_importance_sampling() -> None:
    name = "heteroscedastic"
    rng = np.random.default_rng(3)
    for seed in (0, 1, 2):
        x = sp.instance(name, seed, exact_draws=10).observed
        mean_g, cov_g = sp.grid_moments(sp.grid_posterior(name, x))
        mean_i, sd_i, _ = _importance_moments(name, x, mean_g, 2.0 * cov_g, 4.0, 400_000, rng)
        sd_g = np.sqrt(np.diag(cov_g))
        assert np.all(np.abs(mean_i - mean_g) < 0.015 * sd_g), (seed, mean_i, mean_g)
        assert np.all(np.abs(sd_i / sd_g - 1) < 0.02), (seed, sd_i, sd_g)


def test_the_banana5_direct_sampler_agrees_with_importance_sampling() -> None:
    # Five parameters: no grid; the likelihood times the prior box, reweighted from a wide t proposal.
    name = "banana5"
    rng = np.random.default_rng(5)
    for seed in (0, 1):
        x = sp.instance(name, seed, exact_draws=10, moment_draws=10).observed
        mean_d, cov_d = _direct_moments(name, x, 400_000, seed)
        mean_i, sd_i, ess = _importance_moments(name, x, mean_d, 3.0 * cov_d, 3.0, 1_000_000, rng)
        assert ess > 50_000  # the proposal covers the banana
        sd_d = np.sqrt(np.diag(cov_d))
        assert np.all(np.abs(mean_i - mean_d) < 0.02 * sd_d), (seed, mean_i, mean_d)
        assert np.all(np.abs(sd_i / sd_d - 1) < 0.03), (seed, sd_i, sd_d)


def test_the_grid_is_fine_enough() -> None:
    # Doubling the fine grid's resolution moves no moment by more than 0.2 % of a posterior sd.
    x = sp.instance("heteroscedastic", 0, exact_draws=10).observed
    mean_1, cov_1 = sp.grid_moments(sp.grid_posterior("heteroscedastic", x, fine=1000))
    mean_2, cov_2 = sp.grid_moments(sp.grid_posterior("heteroscedastic", x, fine=2000))
    sd_1, sd_2 = np.sqrt(np.diag(cov_1)), np.sqrt(np.diag(cov_2))
    assert np.all(np.abs(mean_1 - mean_2) < 0.002 * sd_1)
    assert np.all(np.abs(sd_1 / sd_2 - 1) < 0.002)


@pytest.mark.parametrize("name", sp.PROBLEM_NAMES)
def test_each_likelihood_is_the_density_of_its_simulator(name: str) -> None:
    # Importance sampling over summaries x from a heavy-tailed proposal with the likelihood as the
    # target: it integrates to one and puts the simulator's quartiles where the simulations do.
    p = sp.PROBLEMS[name]
    rng = np.random.default_rng(7)
    theta = rng.uniform(p["truth_low"], p["truth_high"])
    sims = sp.simulate_np(name, np.repeat(theta[None], 200_000, axis=0), rng)
    q25, q50, q75 = np.quantile(sims, [0.25, 0.5, 0.75], axis=0)
    scale = (q75 - q25) / 1.35
    chol = np.linalg.cholesky(np.diag((2.0 * scale) ** 2))
    y = _mvt_sample(rng, 400_000, q50, chol, 2.0)
    logw = sp.log_likelihood(name, np.repeat(theta[None], len(y), axis=0), y) - _mvt_logpdf(y, q50, chol, 2.0)
    w = np.exp(logw)
    assert abs(w.mean() - 1) < 0.03, w.mean()
    for q, level in ((q25, 0.25), (q50, 0.5), (q75, 0.75)):
        below = (w[:, None] * (y <= q)).sum(axis=0) / w.sum()
        assert np.all(np.abs(below - level) < 0.015), (name, level, below)


def test_the_jax_simulators_follow_the_numpy_ones() -> None:
    import jax

    sims = sp._jax_simulators()
    assert set(sims) == set(sp.PROBLEM_NAMES)
    rng = np.random.default_rng(11)
    for name, simulate in sims.items():
        p = sp.PROBLEMS[name]
        theta = rng.uniform(p["truth_low"], p["truth_high"]).astype(np.float32)
        keys = jax.random.split(jax.random.key(0), 40_000)
        x_jax = np.asarray(jax.vmap(simulate, in_axes=(0, None))(keys, theta), float)
        x_np = sp.simulate_np(name, np.repeat(theta[None].astype(float), 40_000, axis=0), rng)
        assert x_jax.shape == x_np.shape
        q_jax, q_np = (np.quantile(a, [0.1, 0.5, 0.9], axis=0) for a in (x_jax, x_np))
        spread = q_np[2] - q_np[0]
        assert np.all(np.abs(q_jax - q_np) < 0.04 * spread), (name, q_jax, q_np)


def test_the_shipped_problem_block_stands_alone_and_the_peer_scripts_compile() -> None:
    namespace: dict[str, Any] = {}
    exec(sp.PEER_PRELUDE + sp.problem_source(), namespace)
    theta = np.array([[0.5, -1.0]])
    for name in TWO_D:
        a = namespace["simulate_np"](name, theta, np.random.default_rng(1))
        b = sp.simulate_np(name, theta, np.random.default_rng(1))
        assert np.array_equal(a, b)
    for script in sp.PEER_SCRIPTS.values():
        compile(sp.PEER_PRELUDE + sp.problem_source() + sp.PEER_REQUEST + script, "<peer>", "exec")


def test_instances_are_reproducible_and_their_truths_lie_in_the_inner_region() -> None:
    for name in sp.PROBLEM_NAMES:
        p = sp.PROBLEMS[name]
        a, b = sp.instance(name, 2, exact_draws=50), sp.instance(name, 2, exact_draws=50)
        assert np.array_equal(a.truth, b.truth) and np.array_equal(a.exact_draws, b.exact_draws)
        assert np.all(a.truth >= p["truth_low"]) and np.all(a.truth <= p["truth_high"])
        assert np.all(a.exact_draws >= p["low"]) and np.all(a.exact_draws <= p["high"])
        assert not np.array_equal(a.truth, sp.instance(name, 3, exact_draws=50).truth)


@pytest.mark.parametrize("a", [sp._C5_A, sp._C8_A], ids=["correlated5", "correlated8"])
def test_the_correlated_problems_have_strong_posterior_correlations(a: np.ndarray) -> None:
    cov = np.linalg.inv(a.T @ a)
    sd = np.sqrt(np.diag(cov))
    corr = cov / np.outer(sd, sd)
    d = len(sd)
    assert np.allclose(np.abs(corr), 0.8 ** np.abs(np.subtract.outer(np.arange(d), np.arange(d))))
    assert np.sign(corr[0, 1]) != np.sign(corr[2, 3])
    assert sd[1] == pytest.approx(0.5) and sd[2] == pytest.approx(1.5)


def test_a_problems_fingerprint_follows_its_model_not_the_others(monkeypatch: pytest.MonkeyPatch) -> None:
    before = {n: sp.problem_hash(n) for n in ("linear", "banana")}
    assert before["linear"] != before["banana"] and sp.problem_hash("linear") == before["linear"]
    monkeypatch.setitem(sp._BANANA, "b", 0.6)
    assert sp.problem_hash("banana") != before["banana"]
    assert sp.problem_hash("linear") == before["linear"]


def test_the_energy_distance_is_unbiased_for_equal_laws_and_exact_for_a_shift() -> None:
    rng = np.random.default_rng(0)
    same = [
        sp.energy_distance(rng.standard_normal((800, 2)), np.ones(800), rng.standard_normal((800, 2))) for _ in range(5)
    ]
    assert abs(np.mean(same)) < 0.005
    mu = 1.0
    s = math.sqrt(2)
    e_xy = s * math.sqrt(2 / math.pi) * math.exp(-(mu**2) / (2 * s**2)) + mu * math.erf(mu / (s * math.sqrt(2)))
    exact = 2 * e_xy - 2 * (2 / math.sqrt(math.pi))
    # Monte Carlo sd of one estimate with 1500 + 1500 draws: about 0.025; the mean of 8 is within 0.02.
    shifted = [
        sp.energy_distance(rng.standard_normal((1500, 1)) + mu, np.ones(1500), rng.standard_normal((1500, 1)))
        for _ in range(8)
    ]
    assert np.mean(shifted) == pytest.approx(exact, abs=0.02)
    y = rng.standard_normal((300, 1))
    # Weights count: doubling a point's weight is duplicating it.
    a = rng.standard_normal((50, 2))
    w = np.ones(50)
    w[0] = 2.0
    dup = np.vstack([a, a[:1]])
    assert sp.energy_distance(a, w, y[:300].repeat(2, axis=1)) == pytest.approx(
        sp.energy_distance(dup, np.ones(51), y[:300].repeat(2, axis=1)), rel=0.05
    )


def test_accuracy_scores_exact_and_shifted_draws() -> None:
    inst = sp.instance("linear", 0)
    ref = sp.accuracy(inst.reference_draws, np.ones(len(inst.reference_draws)), inst)
    assert abs(ref["energy_distance"]) < 0.01 and ref["mean_error_in_sd"] < 0.15
    assert np.allclose(ref["sd_ratio"], 1, atol=0.06)
    sd = np.sqrt(np.diag(inst.exact_cov))
    shifted = inst.reference_draws + np.array([2.0, 0.0]) * sd
    s = sp.accuracy(shifted, np.ones(len(shifted)), inst)
    # A shift of 2 sd along the first axis of a correlation-0.8 posterior: Mahalanobis 2 / sqrt(1 - 0.64).
    assert s["mean_error_in_sd"] == pytest.approx(2 / math.sqrt(1 - 0.64), rel=0.05)
    assert s["energy_distance"] > 1.0
    inside = inst.truth[None] + np.zeros((10, 2))
    assert sp.accuracy(inside + np.linspace(-1, 1, 10)[:, None], np.ones(10), inst)["covered_90"] == [True, True]
    assert sp.accuracy(inside + 5.0 + np.linspace(0, 1, 10)[:, None], np.ones(10), inst)["covered_90"] == [False] * 2
    with pytest.raises(ValueError):
        sp.accuracy(np.full((3, 2), np.nan), np.ones(3), inst)


def test_thin_draws_subsamples_equal_weights_and_resamples_unequal_ones() -> None:
    x = np.arange(3000.0)[:, None]
    t, w = sp.thin_draws(x, np.ones(3000), 1000, 0)
    assert len(t) == 1000 and len(np.unique(t)) == 1000 and np.allclose(w, 1e-3)
    weights = np.zeros(3000)
    weights[:10] = 1.0
    t, _ = sp.thin_draws(x, weights, 1000, 0)
    assert set(np.unique(t)) == set(range(10)) and np.all(np.bincount(t[:, 0].astype(int)) == 100)
    assert sp.weighted_quantiles(np.array([0.0, 1.0, 2.0, 3.0]), np.ones(4), [0.5])[0] == pytest.approx(1.5)


def _cell(ed: float, seed: int = 0, **extra: Any) -> dict[str, Any]:
    return {
        "energy_distance": ed + 0.01 * seed,
        "mean_error_in_sd": 0.2,
        "sd_ratio": [1.0, 1.1],
        "covered_90": [True, seed % 2 == 0],
        "num_simulations": 50,
        "run_s": 1.0,
        "process_wall_s": 2.0,
        **extra,
    }


def test_the_cache_keeps_the_last_line_of_a_key_and_skips_broken_lines(tmp_path: Path) -> None:
    path = tmp_path / "cells.jsonl"
    sp.append_cache(path, {"key": "a", "result": {"error": "x"}})
    sp.append_cache(path, {"key": "a", "result": _cell(0.1)})
    with path.open("a") as fh:
        fh.write("{not json\n")
    sp.append_cache(path, {"key": "b", "result": _cell(0.2)})
    cells = sp.load_cache(path)
    assert set(cells) == {"a", "b"} and cells["a"]["result"]["energy_distance"] == 0.1
    assert sp.cell_key("linear", "bolfi", 50, 0, "p", "m") != sp.cell_key("linear", "bolfi", 50, 0, "p2", "m")


def _synthetic(problems: list[str]) -> dict[str, Any]:
    methods = ["jaxabc_surrogate", "sbi_npe", "sbi_snpe", "bolfi"]
    budgets, seeds = [50, 200, 500], [0, 1, 2]
    cells = {}
    for p in problems:
        for b in budgets:
            for s in seeds:
                cells[(p, "exact", b, s)] = _cell(0.0, s)
                cells[(p, "sbi_npe", b, s)] = _cell(0.1, s)
                cells[(p, "bolfi", b, s)] = _cell(0.5, s)
                sur = 0.05 if p != "student" else 0.3
                cells[(p, "jaxabc_surrogate", b, s)] = _cell(sur, s, validated=True)
                if b >= 200:
                    cells[(p, "sbi_snpe", b, s)] = _cell(0.02 if (p, b) == ("linear", 500) else 0.2, s)
    cells[("banana", "bolfi", 50, 1)] = {"error": "did not finish in 10 s"}
    cells[("banana", "bolfi", 200, 2)] = {"not_run": "not in the cache (--cached-only)"}
    for seed in seeds:
        cells[("linear", "bolfi", 200, seed)] = {"not_run": "not in the cache (--cached-only)"}
    summary, verdicts, goal = sp.assemble(cells, problems, methods, budgets, seeds)
    return {
        "format": 2,
        "problems": {p: sp.PROBLEMS[p] for p in problems},
        "method_versions": {"sbi_npe": ["0.27.0"]},
        "seeds": seeds,
        "budgets": budgets,
        "energy_draws": 1000,
        "exact_draws": 2000,
        "summary": summary,
        "closest": verdicts,
        "goal": goal,
        "provenance": {"commit": "0" * 40, "date_utc": "today", "command": "python -m benchmarks.surrogate_peers"},
    }


def test_the_summary_names_the_closest_method_and_judges_the_goal() -> None:
    d = _synthetic(list(sp.PROBLEM_NAMES))
    lin = d["summary"]["linear"]["50"]
    assert lin["sbi_snpe"] == {"skipped": lin["sbi_snpe"]["skipped"]} and "200" in lin["sbi_snpe"]["skipped"]
    assert lin["sbi_npe"]["energy_distance"][0] == pytest.approx(0.11)
    assert lin["sbi_npe"]["coverage_90"] == pytest.approx(5 / 6) and lin["sbi_npe"][
        "coverage_90_joint"
    ] == pytest.approx(2 / 3)
    assert d["closest"]["linear"]["50"]["closest"] == "jaxabc_surrogate"
    assert d["closest"]["banana"]["50"]["ranking"] == ["jaxabc_surrogate", "sbi_npe"]  # bolfi failed a seed
    assert d["summary"]["banana"]["50"]["bolfi"]["seeds_ok"] == 2
    assert d["summary"]["banana"]["200"]["bolfi"]["not_run"] == 1
    assert "bolfi" not in d["closest"]["banana"]["200"]["ranking"]
    student = d["closest"]["student"]["200"]
    assert not student["surrogate_closest"] and student["closest_peer"] == "sbi_npe"
    assert not student["within_seed_error"] and student["energy_distance_excess"] == pytest.approx(0.2)
    assert d["goal"]["met"] and d["goal"]["problems_met"] == ["linear", "banana", "heteroscedastic", "correlated5"]
    assert {(m["problem"], m["budget"]) for m in d["goal"]["misses"]} == {("student", 50), ("student", 200)}
    # Past the goal's budgets the closest method is named too, and the goal does not read it.
    assert d["goal"]["budgets"] == [50, 200] and d["closest"]["linear"]["500"]["closest"] == "sbi_snpe"


def test_the_page_is_generated_from_the_result() -> None:
    from benchmarks.docpages.surrogate import page_surrogate_peers, peers_page

    d = _synthetic(list(sp.PROBLEM_NAMES))
    text = peers_page(json.loads(json.dumps(d)))
    assert text.startswith("# Surrogate against sbi, BOLFI and pyABC")
    assert "Source: `benchmarks/results/surrogate_peers.json`" in text and "commit `" in text
    for name in sp.PROBLEM_NAMES:
        assert f"## {name} (d = " in text
    assert "the goal is met" in text and "- student, B = 50: closest sbi NPE" in text
    assert "on 4 of 5 problems" in text  # correlated8 is for the scaling, not the goal
    scaling = text[text.index("## Scaling in dimension") : text.index("## linear")]
    assert "| 200 | 8 | correlated8 | 0.0" in scaling and "sbi NPE" in scaling
    assert "failed on 1 of 3 seeds: did not finish in 10 s" in text
    assert "not run on 1 of 3 seeds" in text and "failed on 1 of 3 seeds: |" not in text
    assert "Not run in this result (no cached cell on any seed): B = 200: ELFI BOLFI." in text
    assert "not run: sequential rounds" in text
    assert "Beyond the goal, at B = 500, the surrogate is closest on 3 of 5 of these problems" in text
    assert "a peer is closer on linear (sbi SNPE (2 rounds) 0.030 +- " in text
    assert "ELFI BOLFI was not run in 1 (problem, budget) cells (on linear; budgets 200)" in text
    assert "closest in 0" in text and "Cost goal: the surrogate's own time under about 60 s" in text
    assert "(`correlated8`): 1 +- 0 s over 3 seeds, met." in text
    d["summary"]["correlated8"]["500"]["jaxabc_surrogate"]["run_s"] = [300.0, 10.0]
    slow = peers_page(json.loads(json.dumps(d)))
    assert "300 +- 10 s over 3 seeds, not met, 5.0 times over" in slow and "stops scaling" in slow
    assert "the surrogate is closest to exact" in text and "not within their combined seed error" in text
    partial = peers_page(json.loads(json.dumps(_synthetic(["linear"]))))
    assert "not judged" in partial
    old = peers_page({"rows": [], "provenance": d["provenance"]})
    assert "Not saved in the new format yet: run `python -m benchmarks.surrogate_peers`" in old
    assert page_surrogate_peers().startswith("# Surrogate against")


def test_a_cell_is_scored_from_its_stored_draws() -> None:
    inst = sp.instance("linear", 1)
    raw = {"num_simulations": 60, "run_s": 1.0, "particles": inst.reference_draws.tolist()}
    cell = sp.score(raw, inst, 50, 1000)
    assert "particles" not in cell and cell["over_budget"] and abs(cell["energy_distance"]) < 0.01
    weighted = sp.score({**raw, "weights": [1.0] * 999 + [0.0]}, inst, 100, 1000)
    assert not weighted["over_budget"] and weighted["energy_distance"] == pytest.approx(
        cell["energy_distance"], abs=0.01
    )
    assert sp.score({"error": "boom", "process_wall_s": 3.0}, inst, 50, 1000) == {
        "error": "boom",
        "process_wall_s": 3.0,
    }
    assert "scoring failed" in sp.score({"particles": [[float("nan")] * 2] * 3}, inst, 50, 1000)["error"]
    assert sp.sbi_batch_size(50) == 10 and sp.sbi_batch_size(200) == 20 and sp.sbi_batch_size(5000) == 50


def _old_cells(path: Path, old_hash: str) -> list[tuple[str, str, int, int]]:
    """Surrogate cells of an earlier jaxabc code hash in a cache file; returns their grid."""
    grid = []
    for problem in ("linear", "banana"):
        for budget in (50, 200):
            for seed in (0, 1):
                c = (problem, "jaxabc_surrogate", budget, seed)
                result = {"particles": [[float(seed), float(budget)]], "num_simulations": budget - 1}
                key = sp.cell_key(*c, "p" + problem, old_hash)
                sp.append_cache(
                    path,
                    {"key": key, "problem": problem, "method": c[1], "budget": budget, "seed": seed, "result": result},
                )
                grid.append(c)
    return grid


def test_carry_over_rekeys_cells_only_when_the_checked_ones_reproduce(tmp_path: Path) -> None:
    path = tmp_path / "cells.jsonl"
    grid = _old_cells(path, "old")
    p_hash = {"linear": "plinear", "banana": "pbanana"}
    m_hash = {"jaxabc_surrogate": "new"}
    runs: list[tuple[str, str, int, int]] = []

    def same(p: str, m: str, b: int, s: int) -> dict:
        runs.append((p, m, b, s))
        return {"particles": [[float(s), float(b)]], "num_simulations": b - 1, "run_s": 1.0}

    carried = sp.carry_over(sp.load_cache(path), path, grid, p_hash, m_hash, 2, same)
    # The two checks are at the largest budget, one per problem; the other six are carried.
    assert carried == 6 and sorted(runs) == [
        ("banana", "jaxabc_surrogate", 200, 0),
        ("linear", "jaxabc_surrogate", 200, 0),
    ]
    cells = sp.load_cache(path)
    new = {k: c for k, c in cells.items() if k.endswith("|new")}
    assert len(new) == 8
    assert sum("carried_from" in c["result"] for c in new.values()) == 6
    assert all(c["result"].get("carried_from") in (None, "old") for c in new.values())
    # Nothing left to carry on a second call.
    assert sp.carry_over(cells, path, grid, p_hash, m_hash, 2, same) == 0


def test_carry_over_refuses_when_a_check_changes_the_draws(tmp_path: Path) -> None:
    path = tmp_path / "cells.jsonl"
    grid = _old_cells(path, "old")
    p_hash = {"linear": "plinear", "banana": "pbanana"}

    def different(p: str, m: str, b: int, s: int) -> dict:
        return {"particles": [[float(s) + 1e-4, float(b)]], "num_simulations": b - 1}

    with pytest.raises(SystemExit, match="carry-over refused"):
        sp.carry_over(sp.load_cache(path), path, grid, p_hash, {"jaxabc_surrogate": "new"}, 2, different)
    carried = [c for c in sp.load_cache(path).values() if "carried_from" in c["result"]]
    assert carried == []


def test_cells_timed_beside_other_work_count_for_accuracy_not_time() -> None:
    cells = [_cell(0.1, 0), _cell(0.1, 1, run_s=3.0), _cell(0.1, 2, run_s=700.0, process_wall_s=750.0, cpu_shared=True)]
    s = sp.summarise(cells)
    assert s["seeds_ok"] == 3 and s["timed_seeds"] == 2
    assert s["run_s"][0] == pytest.approx(2.0) and s["process_wall_s"][0] == pytest.approx(2.0)
    assert s["energy_distance"][0] == pytest.approx(0.11)


def test_a_failure_reads_as_one_reason_however_many_seeds_hit_it() -> None:
    from benchmarks.docpages.surrogate import _peer_row

    nuts = "exit 1: ValueError: NUTS: Cannot find acceptable stepsize starting from point [{}]. All trials ended."
    s = {"seeds": 5, "seeds_ok": 0, "not_run": 3, "errors": [nuts.format(" 0.8 -3.2"), nuts.format("3.4  5.39")]}
    note = _peer_row("50", "bolfi", s, 5)[-1]
    assert note == (
        "not run on 3 of 5 seeds; failed on 2 of 5 seeds: "
        "ValueError: NUTS: Cannot find acceptable stepsize starting from point. All trials ended."
    )


def test_the_early_stop_section_judges_the_runs_that_stopped_before_the_budget() -> None:
    from benchmarks.docpages.surrogate import _early_stop_section, early_stop_rows

    def cell(problem: str, budget: int, sims: int, sd: list[float], method: str = "jaxabc_surrogate") -> dict:
        return {"problem": problem, "method": method, "budget": budget, "num_simulations": sims, "sd_ratio": sd}

    cells = [
        cell("linear", 200, 178, [0.98, 1.0]),
        cell("linear", 200, 170, [1.0, 1.02]),
        cell("linear", 200, 198, [0.5, 0.5]),  # spent the budget: not an early stop
        cell("banana", 500, 250, [0.8, 0.95]),
        cell("banana", 500, 260, [0.84, 1.15]),
        cell("banana", 500, 260, [0.1, 0.1], method="sbi_npe"),  # another method
        cell("student", 50, 46, [0.5]),  # near its budget: the batch decided
    ]
    rows = early_stop_rows(cells)
    assert [(r["problem"], r["budget"], r["runs"], r["seeds"]) for r in rows] == [
        ("linear", 200, 2, 3),
        ("banana", 500, 2, 2),
    ]
    assert rows[0]["within"] and rows[0]["low"] == pytest.approx(0.99) and rows[0]["high"] == pytest.approx(1.01)
    assert not rows[1]["within"] and rows[1]["low"] == pytest.approx(0.82) and rows[1]["high"] == pytest.approx(1.05)
    assert rows[1]["mean"] == pytest.approx((0.875 + 0.995) / 2)
    text = _early_stop_section({"cells": cells})
    assert "| 200 | linear | 2 of 3 | 1.00 +- 0.01 | 0.99-1.01 | yes |" in text
    assert (
        "Overconfident (a parameter's mean sd ratio below 0.90) in 1 of 2 (problem, budget) pairs: banana at B = 500"
        in text
    )
    assert "`tolerance=0`" in text and "conservative" not in text
    assert "Not overconfident" in _early_stop_section({"cells": cells[:2]})
    assert _early_stop_section({"cells": []}) == ""


def _saved_result(machine: dict[str, Any]) -> dict[str, Any]:
    cells = [
        {"problem": "linear", "method": "sbi_npe", "budget": 50, "seed": 0, **_cell(0.1)},
        {"problem": "linear", "method": "bolfi", "budget": 50, "seed": 0, "error": "exit 1: boom"},
        {"problem": "linear", "method": "bolfi", "budget": 500, "seed": 0, "not_run": "not in the cache"},
        {"problem": "linear", "method": "jaxabc_surrogate", "budget": 50, "seed": 0, **_cell(0.2)},
        {"problem": "linear", "method": "exact", "budget": 50, "seed": 0, **_cell(0.0)},
        {"problem": "banana", "method": "sbi_npe", "budget": 50, "seed": 0, **_cell(0.3)},
        {"problem": "linear", "method": "pyabc_abcsmc", "budget": 50, "seed": 1, **_cell(0.4, imported_from="c0")},
    ]
    return {
        "cells": cells,
        "problem_hash": {"linear": "pl", "banana": "pb-old"},
        "provenance": {"commit": "c1", "tree_clean": True, "machine": machine},
    }


def test_imported_peer_cells_are_the_unchanged_ones_and_keep_their_origin() -> None:
    here = {"cpu": "CPU A", "cpu_count": 2, "native_kernel_instruction_set": {"simd": ["avx2"]}}
    saved = _saved_result(here)
    methods = ["sbi_npe", "bolfi", "pyabc_abcsmc", "jaxabc_surrogate"]
    m_hash = {"sbi_npe": "s", "bolfi": "b", "pyabc_abcsmc": "a", "jaxabc_surrogate": "j"}
    hashes = {"method": {"sbi_npe": "s", "bolfi": "b", "pyabc_abcsmc": "a"}, "scoring": sp.scoring_hash()}
    p_hash = {"linear": "pl", "banana": "pb"}
    taken = sp.import_cells(saved, hashes, ["linear", "banana"], methods, p_hash, m_hash, here)
    # Neither jaxabc's cell, nor the exact row, nor a cell not run, nor a problem whose model changed.
    assert sorted(taken) == [
        ("linear", "bolfi", 50, 0),
        ("linear", "pyabc_abcsmc", 50, 1),
        ("linear", "sbi_npe", 50, 0),
    ]
    assert taken[("linear", "sbi_npe", 50, 0)]["imported_from"] == "c1"
    assert taken[("linear", "pyabc_abcsmc", 50, 1)]["imported_from"] == "c0"  # the commit that ran it
    assert taken[("linear", "bolfi", 50, 0)]["error"] == "exit 1: boom"
    assert not any(c.get("timed_elsewhere") for c in taken.values())
    # A peer whose code or version changed is run again.
    changed = sp.import_cells(saved, hashes, ["linear"], methods, p_hash, {**m_hash, "bolfi": "b2"}, here)
    assert ("linear", "bolfi", 50, 0) not in changed and len(changed) == 2
    # Other metric code: nothing is taken.
    assert sp.import_cells(saved, {**hashes, "scoring": "x"}, ["linear"], methods, p_hash, m_hash, here) == {}
    # Another CPU (or the same name with other instruction sets): scores kept, times left out.
    other = {**here, "native_kernel_instruction_set": {"simd": ["avx2", "avx512f"]}}
    elsewhere = sp.import_cells(saved, hashes, ["linear"], methods, p_hash, m_hash, other)
    assert all(c["timed_elsewhere"] for c in elsewhere.values())
    s = sp.summarise([elsewhere[("linear", "sbi_npe", 50, 0)], _cell(0.1, 1, run_s=3.0)])
    assert s["seeds_ok"] == 2 and s["timed_seeds"] == 1 and s["run_s"][0] == pytest.approx(3.0)


def test_saved_hashes_come_from_the_result_or_from_its_commits_code() -> None:
    import subprocess

    recorded = {"method_hash": {"bolfi": "b"}, "scoring_hash": "x"}
    assert sp.saved_hashes(recorded, ["bolfi"]) == {"method": {"bolfi": "b"}, "scoring": "x"}
    with pytest.raises(SystemExit, match="no clean commit"):
        sp.saved_hashes({"provenance": {"commit": "abc", "tree_clean": False}}, ["bolfi"])
    with pytest.raises(SystemExit, match="not in this clone"):
        sp.saved_hashes({"provenance": {"commit": "0" * 40, "tree_clean": True}}, ["bolfi"])
    head = subprocess.run(["git", "-C", str(sp.ROOT), "rev-parse", "HEAD"], capture_output=True, text=True)
    if head.returncode != 0:
        pytest.skip("not a git clone")
    unchanged = subprocess.run(
        ["git", "-C", str(sp.ROOT), "diff", "--quiet", "HEAD", "--", "benchmarks/surrogate_peers.py"]
    )
    if unchanged.returncode != 0:
        pytest.skip("benchmarks/surrogate_peers.py differs from HEAD's")
    at_head = sp.saved_hashes({"provenance": {"commit": head.stdout.strip(), "tree_clean": True}}, ["bolfi", "sbi_npe"])
    assert at_head == {"method": {m: sp.method_hash(m) for m in ("bolfi", "sbi_npe")}, "scoring": sp.scoring_hash()}


def test_the_page_says_which_peer_cells_were_imported_and_whose_times_are_left_out() -> None:
    from benchmarks.docpages.surrogate import _cache_note

    cells = [_cell(0.1, imported_from="abcdef123456789", timed_elsewhere=True), _cell(0.1, imported_from="abcdef1234")]
    note = _cache_note({"cells": cells})
    assert "2 peer cells were run at commit abcdef1234 and taken from that result" in note
    assert "1 of them ran on another machine, so their wall times are left out" in note
    assert _cache_note({"cells": [_cell(0.1)]}) == ""


def test_a_file_that_is_not_a_saved_result_is_refused_in_one_line(tmp_path: Path) -> None:
    bad = tmp_path / "notes.txt"
    bad.write_text("not json")
    with pytest.raises(SystemExit, match="is not a result JSON"):
        sp.load_saved(bad)
    other = tmp_path / "other.json"
    other.write_text('{"benchmark": "helium_table1"}')
    with pytest.raises(SystemExit, match="holds no 'cells' list"):
        sp.load_saved(other)
    good = tmp_path / "peers.json"
    good.write_text('{"cells": []}')
    assert sp.load_saved(good) == {"cells": []}


def test_keep_other_problems_takes_the_saved_cells_of_the_others_and_refuses_what_would_mix(tmp_path: Path) -> None:
    peers = ["sbi_npe", "bolfi"]
    methods = ["jaxabc_surrogate", *peers]
    saved = {
        "methods": methods,
        "budgets": [50],
        "seeds": [0],
        "problems": {"linear": {}, "banana": {}},
        "problem_hash": {"linear": "pl", "banana": "pb"},
        "method_hash": {m: sp.method_hash(m) for m in peers},
        "scoring_hash": sp.scoring_hash(),
        "cells": [
            {"problem": p, "method": m, "budget": 50, "seed": 0, "energy_distance": 0.1}
            for p in ("linear", "banana")
            for m in ("exact", *methods)
        ],
    }
    path = tmp_path / "saved.json"

    def keep(result: dict[str, Any], *extra: str) -> tuple[dict, dict]:
        path.write_text(json.dumps(result))
        argv = ["--problems", "linear", "--methods", *methods, "--budgets", "50", "--seeds", "0", *extra]
        return sp.keep_other_problems(sp.parse([*argv, "--import-cells", str(path), "--keep-other-problems"]))

    kept, hashes = keep(saved)
    # Every saved cell of the other problem (jaxabc's and the exact row too), none of the one run.
    assert sorted(kept) == sorted(("banana", m, 50, 0) for m in ("exact", *methods))
    assert kept[("banana", "bolfi", 50, 0)] == {"energy_distance": 0.1}
    assert hashes == {"banana": "pb"}
    with pytest.raises(SystemExit, match="budgets"):
        keep({**saved, "budgets": [50, 100]})
    with pytest.raises(SystemExit, match="the code of bolfi changed"):
        keep({**saved, "method_hash": {**saved["method_hash"], "bolfi": "old"}})
    with pytest.raises(SystemExit, match="other metric code"):
        keep({**saved, "scoring_hash": "old"})
    with pytest.raises(SystemExit, match="needs --import-cells"):
        sp.keep_other_problems(sp.parse(["--problems", "linear", "--keep-other-problems"]))
