"""water_misfit takes the finished run's surrogate state from its checkpoint, and only that run's."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks import water_misfit


def _files(tmp_path: Path, shift: float = 0.0) -> tuple[Path, Path, Path]:
    rng = np.random.default_rng(0)
    particles, theta = rng.normal(size=(5, 2)), rng.normal(size=(3, 2))
    checkpoint, record = tmp_path / "checkpoint.npz", tmp_path / "record.npz"
    np.savez(
        checkpoint,
        **{"state/.count": np.array(3), "state/.thetas": theta, "posterior/particles": particles + shift},
        **{"records/theta": theta},
    )
    np.savez(record, particles=particles, record_theta=theta)
    return checkpoint, record, tmp_path / "state.npz"


def test_the_state_of_the_saved_runs_checkpoint_is_kept(tmp_path: Path) -> None:
    checkpoint, record, state = _files(tmp_path)
    assert water_misfit.take_state(checkpoint, record, state)
    with np.load(state) as z:
        assert sorted(z.files) == [".count", ".thetas"]
        assert int(z[".count"]) == 3


def test_a_checkpoint_of_another_run_is_refused_and_none_is_no_copy(tmp_path: Path) -> None:
    checkpoint, record, state = _files(tmp_path, shift=1.0)
    with pytest.raises(SystemExit, match="is not the checkpoint of the run saved"):
        water_misfit.take_state(checkpoint, record, state)
    assert not state.exists()
    assert not water_misfit.take_state(tmp_path / "none.npz", record, state)


def test_a_checkpoint_without_its_saved_run_is_refused(tmp_path: Path) -> None:
    checkpoint, record, state = _files(tmp_path)
    record.unlink()
    with pytest.raises(SystemExit, match="is missing"):
        water_misfit.take_state(checkpoint, record, state)
    assert not state.exists()
