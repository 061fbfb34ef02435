"""The run options every entry point builds (:class:`jaxabc.driver.options.RunOptions`)."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from jaxabc.driver.options import RunOptions, Stopping


def test_options_round_trip_through_run_keywords():
    options = RunOptions.from_keywords(
        seed=np.int64(7),
        executor="serial",
        num_steps=3,
        max_simulations=500,
        checkpoint_dir="ck",
        resume=True,
        stop_after=2,
        progress=True,
        dtype="float64",
        metadata={"a": 1},
    )
    assert options.seed == 7 and type(options.seed) is int
    keywords = options.keywords()
    keywords["stop_after"] = keywords.pop("stop_after_iterations")
    assert RunOptions.from_keywords(**keywords) == options
    with pytest.raises(dataclasses.FrozenInstanceError):
        options.seed = 1  # type: ignore[misc]


@pytest.mark.parametrize(
    ("keywords", "error", "match"),
    [
        (dict(seed=-1), ValueError, r"0 <= seed < 2\*\*32"),
        (dict(seed=1.5), TypeError, "seed must be an integer"),
        (dict(dtype="float16"), ValueError, "dtype must be 'float32' or 'float64'"),
        (dict(max_failure_fraction=0.0), ValueError, r"max_failure_fraction must lie in \(0, 1\]"),
        (dict(num_steps=0), ValueError, "num_steps must be at least 1"),
    ],
)
def test_bad_options_are_refused_when_built(keywords, error, match):
    with pytest.raises(error, match=match):
        RunOptions.from_keywords(**keywords)


def test_a_stopping_rule_is_one_of_the_four_limits():
    assert not Stopping(stop_after=3).has_rule
    assert Stopping(max_wall_time=1.0).has_rule
