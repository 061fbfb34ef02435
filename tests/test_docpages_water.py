"""The water results page says when a surrogate run's checks judged another fit than its draws'."""

from __future__ import annotations

from typing import Any

import pytest

from benchmarks.docpages import water


def _fits(refit_mean: list[float]) -> dict[str, Any]:
    at = {"surrogate_estimate": -600.0, "paper_estimate": -650.0, "tip4p": -640.0}
    one = {"gp_objective": 100.0, "posterior_mean": [0.35, 0.2], "posterior_sd": [0.001, 0.01], "log_posterior": at}
    return {"sampled": one, "refit": one | {"gp_objective": 104.5, "posterior_mean": refit_mean}}


def test_fits_apart_is_the_largest_shift_in_the_draws_sds() -> None:
    assert water._fits_apart(_fits([0.352, 0.2])) == pytest.approx(2.0)
    assert water._fits_apart(_fits([0.35, 0.25])) == pytest.approx(5.0)


def test_fits_far_apart_void_the_validated_cell(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(water, "load", lambda name: {"fits": _fits([0.32, 0.67])})
    assert "another fit" in water._validated_cell(True)
    text = water._two_fits({"fits": _fits([0.32, 0.67])})
    assert "does not vouch" in text and "scoring 4.5 better" in text
    assert water._validated_cell(False) == "**no**"


def test_fits_close_together_keep_the_pass(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(water, "load", lambda name: {"fits": _fits([0.351, 0.21])})
    assert water._validated_cell(True) == "yes"
    assert "speaks for the reported draws" in water._two_fits({"fits": _fits([0.351, 0.21])})
    monkeypatch.setattr(water, "load", lambda name: None)
    assert water._validated_cell(True) == "yes"
