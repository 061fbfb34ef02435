"""Published-model discrepancy bounds (benchmarks/water_box_sensitivity.py): the bound rule, its
refusals, and the reuse identity on a saved model choice."""

from __future__ import annotations

import json

import numpy as np
import pytest

from benchmarks._common import RESULTS, ROOT
from benchmarks._published_bounds import published_model_bounds
from benchmarks.water_box_sensitivity import bounded_box, family_variant
from jaxabc.model_choice import load_model_choice

PUBLISHED = {
    "data": "xray",
    "temperature_k": 295.15,
    "summary_names": ["a", "b", "c"],
    "observed": [1.0, 10.0, 0.5],
    "models": {"m1": {"mean": [1.2, 7.0, 0.5]}, "m2": {"mean": [0.7, 10.5, 0.45]}},
}


def test_family_bound_is_the_largest_published_misfit_per_group() -> None:
    bounds = published_model_bounds(PUBLISHED, ["c", "a", "b"], {"g": [0, 1], "h": [2]}, "xray", 295.15)
    assert bounds == pytest.approx({"g": 0.3, "h": 3.0})


@pytest.mark.parametrize(
    ("fitted", "data", "temperature", "match"),
    [
        (["a", "z"], "xray", 295.15, "lack"),
        (["a", "b"], "neutron", 295.15, "published-model runs are for data"),
        (["a", "b"], "xray", 298.15, "published-model runs are for data"),
    ],
)
def test_published_model_bounds_refuse_other_data_or_missing_summaries(fitted, data, temperature, match) -> None:
    with pytest.raises(ValueError, match=match):
        published_model_bounds(PUBLISHED, fitted, {"g": [0, 1]}, data, temperature)


def _saved(name: str = "water_model_choice"):
    path = RESULTS / f"{name}.json"
    if not path.is_file():
        pytest.skip(f"{name} not saved")
    d = json.loads(path.read_text())
    return d, load_model_choice(ROOT / d["saved_result"])


def test_bounds_at_or_above_the_runs_reproduce_its_probabilities() -> None:
    """Bounds capped at the run's own give back the run's evidence exactly (the reuse identity
    with P(theta in B | data) = 1); a narrower bound cuts posterior mass and moves it."""
    d, choice = _saved()
    groups = d["settings"]["discrepancy"]["groups"]
    huge = dict.fromkeys(groups, 1e6)
    same = family_variant(choice, huge, 1.0)
    np.testing.assert_allclose(same["log_evidence"], choice.log_evidence, rtol=0, atol=1e-12)
    np.testing.assert_allclose(same["probabilities"], choice.probabilities, rtol=0, atol=1e-12)
    assert all(v == 0.0 for cut in same["posterior_share_cut"].values() for v in cut.values())
    # Half of one group's run bound: the cut share is the weight above it, and the box says so.
    group, column = "D", "discrepancy_sd[D]"
    half = dict.fromkeys(groups, 1e6) | {group: 0.5 * d["settings"]["discrepancy"]["max_sd"][list(groups).index(group)]}
    post = choice.posteriors[0]
    low, high = bounded_box(post, half, 1.0, only=group)
    np.testing.assert_array_equal(low, post.prior.low)
    j = list(post.names).index(column)
    assert high[j] == pytest.approx(half[group]) and np.all(np.delete(high, j) == np.delete(post.prior.high, j))
    moved = family_variant(choice, half, 1.0, only=group)
    x, w = np.asarray(post.particles), np.asarray(post.weights)
    assert moved["posterior_share_cut"][choice.names[0]][group] == pytest.approx(w @ (x[:, j] > half[group]) / w.sum())
    assert moved["verdict"] == "undecided" or moved["verdict"].startswith("preferred: ")
