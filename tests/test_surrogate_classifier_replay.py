"""The classifier replay writes one part per water record and keeps the others' entries."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from benchmarks import surrogate_classifier_replay as replay


def _record(path: Path, seed: int) -> None:
    """A small saved record: 3 batches of 8 runs in a 2-D box, failing where x0 + x1 > 1.2."""
    rng = np.random.default_rng(seed)
    low, high = np.array([0.0, 1.0]), np.array([2.0, 3.0])
    theta = low + (high - low) * rng.uniform(size=(24, 2))
    x = (theta - low) / (high - low)
    status = np.where(x.sum(1) > 1.2, 1, 0)
    meta = {"prior": {"low": low.tolist(), "high": high.tolist()}}
    np.savez(
        path,
        metadata=json.dumps(meta),
        record_theta=theta,
        record_status=status,
        record_iteration=np.repeat(np.arange(3), 8),
    )


def test_parts_are_written_and_merged(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(replay, "RESULTS", tmp_path)
    for seed, stem in enumerate(("water_a_robust_surrogate", "water_b_paper_surrogate")):
        _record(tmp_path / f"{stem}.npz", seed)
    out = tmp_path / "replay.json"

    first = replay.main(["--record", "water_a_robust_surrogate", "--output", str(out)])
    assert list(first["runs"]) == ["water_a_robust_surrogate"]
    run = first["runs"]["water_a_robust_surrogate"]
    assert run["num_runs"] == 24 and run["num_replayed"] == 16  # batches 1 and 2
    assert run["num_failed"] == int(np.sum(np.load(tmp_path / "water_a_robust_surrogate.npz")["record_status"]))
    for scores in run["classifiers"].values():
        assert 0.0 <= scores["brier"] <= 1.0
        assert scores["runs_at_or_above_level"] + scores["runs_below_level"] == 16

    replay.main(["--record", "water_b_paper_surrogate", "--output", str(out)])
    saved = json.loads(out.read_text())
    assert list(saved["runs"]) == ["water_a_robust_surrogate", "water_b_paper_surrogate"]
    assert saved["runs"]["water_a_robust_surrogate"] == run  # the earlier part is kept as it was
    parts = saved["provenance_parts"]
    assert set(parts) == {"water_a_robust_surrogate", "water_b_paper_surrogate"}
    # Each part names only its own record as an input, so a rerun of one record stales one part.
    for stem, prov in parts.items():
        inputs = json.dumps(prov["fingerprint"])
        assert f"{stem}.npz" in inputs
        other = ({"water_a_robust_surrogate", "water_b_paper_surrogate"} - {stem}).pop()
        assert f"{other}.npz" not in inputs


def test_unknown_record_is_refused(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(replay, "RESULTS", tmp_path)
    _record(tmp_path / "water_a_robust_surrogate.npz", 0)
    with pytest.raises(SystemExit):
        replay.main(["--record", "water_missing_surrogate", "--output", str(tmp_path / "r.json")])
    assert not (tmp_path / "r.json").exists()
