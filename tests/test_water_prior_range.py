"""The verdict of benchmarks/water_prior_range.py tells a phase limit from undefined summaries."""

from __future__ import annotations

from benchmarks.water_prior_range import verdict


def _row(factor: float, status: str, liquid: bool, **extra) -> dict:
    return {"model": "TIP4P", "epsilon_factor": factor, "seed": 0, "status": status, "liquid": liquid, **extra}


def test_all_liquid_means_no_physical_limit() -> None:
    rows = [_row(1.0, "ok", True, density_kg_m3=1000.0), _row(2.5, "ok", True, density_kg_m3=945.0)]
    text = verdict(rows, [1.0, 2.5])
    assert text.startswith("2 of 2 runs") and "no physical limit bounds the box" in text


def test_undefined_summaries_are_not_called_a_phase_limit() -> None:
    rows = [
        _row(1.0, "ok", True, density_kg_m3=1000.0),
        _row(1.6, "summaries undefined", True, density_kg_m3=965.6, reason="no first peak/minimum found for S5"),
    ]
    text = verdict(rows, [1.0, 1.6])
    assert "no physical limit" in text and "not a phase limit" in text and "x1.6 seed 0 (density 966)" in text


def test_a_vaporised_run_is_a_physical_limit() -> None:
    rows = [_row(1.0, "ok", True, density_kg_m3=1000.0), _row(3.0, "failed", False, reason="vapour")]
    text = verdict(rows, [1.0, 3.0])
    assert "1 of 2 runs" in text and "meets a physical limit" in text and "x3 seed 0 (vapour)" in text
