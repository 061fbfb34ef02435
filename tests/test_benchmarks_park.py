"""Parking a long run's checkpoint in the git tree between sittings (benchmarks/park.py)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from benchmarks import park
from benchmarks.registry import REGISTRY, Entry

ENTRY = Entry("run:part", "benchmarks/results/run.json", "python -m x", resumable=("runs/cache/ckpt",))


def _checkpoint(root: Path, text: str) -> Path:
    folder = root / "runs/cache/ckpt"
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "checkpoint.npz").write_text(text)
    return folder


def test_save_restore_drop_round_trip(tmp_path: Path) -> None:
    folder = _checkpoint(tmp_path, "step 106")
    assert park.save(ENTRY, tmp_path) == ["runs/cache/ckpt"]
    parked = park.parked_folder(ENTRY, tmp_path)
    assert parked == tmp_path / "benchmarks/parked/run__part"
    assert (parked / "runs/cache/ckpt/checkpoint.npz").read_text() == "step 106"
    stamp = json.loads((parked / park.STAMP).read_text())
    assert stamp["paths"] == ["runs/cache/ckpt"] and stamp["bytes"] == len("step 106")
    # A new machine: runs/ is gone, the parked copy comes back.
    (folder / "checkpoint.npz").unlink()
    folder.rmdir()
    assert park.restore(ENTRY, tmp_path) == ["runs/cache/ckpt"]
    assert (folder / "checkpoint.npz").read_text() == "step 106"
    assert park.drop(ENTRY, tmp_path) and not parked.exists()
    assert not park.drop(ENTRY, tmp_path)


def test_restore_keeps_a_local_checkpoint_unless_forced(tmp_path: Path) -> None:
    folder = _checkpoint(tmp_path, "step 106")
    park.save(ENTRY, tmp_path)
    (folder / "checkpoint.npz").write_text("step 150")  # this machine went on since
    assert park.restore(ENTRY, tmp_path) == []
    assert (folder / "checkpoint.npz").read_text() == "step 150"
    assert park.restore(ENTRY, tmp_path, force=True) == ["runs/cache/ckpt"]
    assert (folder / "checkpoint.npz").read_text() == "step 106"


def test_save_refuses_what_is_not_a_checkpoint(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match="declares no resumable"):
        park.save(Entry("other", "benchmarks/results/o.json", "x"), tmp_path)
    with pytest.raises(SystemExit, match="nothing to park"):
        park.save(ENTRY, tmp_path)
    folder = _checkpoint(tmp_path, "")
    (folder / "cache.bin").write_bytes(b"\0" * (park.MAX_BYTES + 1))
    with pytest.raises(SystemExit, match="more than"):
        park.save(ENTRY, tmp_path)


def test_resumable_paths_are_untracked_checkpoints() -> None:
    """What the registry parks lies under runs/ (untracked), one folder per entry."""
    resumable = [(e.name, p) for e in REGISTRY for p in e.resumable]
    assert resumable, "the paper preset's checkpoint is parkable"
    assert all(p.startswith("runs/") for _, p in resumable)


def test_regenerate_continues_from_the_parked_checkpoint_and_drops_it(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """On a machine without runs/, regenerate restores the parked checkpoint before the command
    runs (the command sees it) and drops the parked copy once the command succeeded."""
    from benchmarks import regenerate
    from benchmarks.status import Status

    _checkpoint(tmp_path, "step 106")
    park.save(ENTRY, tmp_path)
    (tmp_path / "runs/cache/ckpt/checkpoint.npz").unlink()  # a new machine: an empty runs folder
    seen = tmp_path / "seen.txt"
    command = (
        "python -c \"import pathlib; pathlib.Path('seen.txt')"
        ".write_text(pathlib.Path('runs/cache/ckpt/checkpoint.npz').read_text())\""
    )
    entry = Entry("run:part", "benchmarks/results/run.json", command, resumable=ENTRY.resumable)
    monkeypatch.setattr(regenerate, "ROOT", tmp_path)
    monkeypatch.setattr(regenerate, "REGISTRY", (entry,))
    states = iter(["stale", "current"])
    monkeypatch.setattr(
        regenerate, "status_of", lambda e, quick=False: Status(e.name, e.output, next(states, "current"), cost_s=1.0)
    )
    assert regenerate.main(["--budget", "1m", "--only", "run:part"]) == 0
    assert seen.read_text() == "step 106"
    assert not park.parked_folder(entry, tmp_path).exists()
