"""Integer seeds for external programs, derived from particle keys (jaxabc.seeding)."""

from __future__ import annotations

import pickle

import jax
import numpy as np
import pytest
from scipy import stats

from jaxabc.seeding import seed_from_key, seeds_from_key


def test_typed_key_and_its_raw_data_give_the_same_seeds() -> None:
    # Executors hand host simulators jax.random.key_data(key): a worker that received the
    # pickled raw data must derive the seeds the serial path derives from the typed key.
    key = jax.random.fold_in(jax.random.key(3), 7)
    raw = pickle.loads(pickle.dumps(np.asarray(jax.random.key_data(key))))
    assert raw.dtype == np.uint32 and raw.shape == (2,)
    assert seeds_from_key(key, 5) == seeds_from_key(raw, 5)
    assert seed_from_key(key) == seeds_from_key(key, 1)[0] == seed_from_key(raw)
    # A legacy PRNGKey is the same uint32[2] data.
    assert seeds_from_key(jax.random.PRNGKey(11), 3) == seeds_from_key(jax.random.key(11), 3)


def test_seeds_are_python_ints_in_range_and_deterministic() -> None:
    key = jax.random.key(0)
    seeds = seeds_from_key(key, 1000)
    assert len(seeds) == 1000 and all(type(s) is int for s in seeds)
    assert all(1 <= s < 2**31 - 1 for s in seeds)
    assert seeds == seeds_from_key(key, 1000)
    assert len(set(seeds)) == 1000  # 1000 draws from 2**31: a collision has probability ~2e-4
    assert seeds_from_key(key, 0) == []


def test_particles_get_distinct_seeds() -> None:
    keys = jax.random.split(jax.random.key(1), 100)
    seeds = [seed_from_key(k) for k in keys]
    assert len(set(seeds)) == len(seeds)


def test_small_high_is_uniform_over_one_to_high_minus_one() -> None:
    # [1, high) with high = 11: ten values, each with probability 1/10.
    seeds = np.asarray(seeds_from_key(jax.random.key(2), 5000, high=11))
    assert seeds.min() == 1 and seeds.max() == 10
    counts = np.bincount(seeds, minlength=11)[1:]
    # Chi-square with 9 degrees of freedom; a uniform generator fails p < 1e-3 once in 1000 seeds.
    assert stats.chisquare(counts).pvalue > 1e-3, counts


def test_high_of_two_gives_only_ones() -> None:
    assert seeds_from_key(jax.random.key(4), 20, high=2) == [1] * 20


@pytest.mark.parametrize(
    ("key", "num", "high", "match"),
    [
        (jax.random.key(0), -1, 100, "num must be >= 0"),
        (jax.random.key(0), 1, 1, r"high must be in \[2, 2\*\*31 - 1\]"),
        (jax.random.key(0), 1, 2**31, r"high must be in \[2, 2\*\*31 - 1\]"),
        (np.zeros(3, np.uint32), 1, 100, r"uint32\[2\].*got uint32\[3\]"),
        (np.zeros(2, np.float32), 1, 100, r"uint32\[2\].*got float32\[2\]"),
    ],
)
def test_bad_arguments_say_what_is_expected(key, num: int, high: int, match: str) -> None:
    with pytest.raises(ValueError, match=match):
        seeds_from_key(key, num, high)
