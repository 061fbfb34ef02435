"""Optional dependencies (pyproject extras) fail with a message that names the extra to install."""

from __future__ import annotations

import sys

import numpy as np
import pytest

import jaxabc


def test_plot_without_matplotlib_names_the_plotting_extra(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    prior = jaxabc.Uniform([0.0, 0.0], [1.0, 1.0], names=("a", "b"))
    result = jaxabc.ABCResult.from_sample(np.random.default_rng(0).uniform(size=(50, 2)), np.ones(50), prior)
    monkeypatch.setitem(sys.modules, "matplotlib", None)  # import matplotlib now raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'jaxabc\[plotting\]'"):
        result.plot_posterior(tmp_path / "posterior.png")


def test_trajectory_without_mdtraj_names_the_water_extra(monkeypatch: pytest.MonkeyPatch, tmp_path) -> None:
    from md.water.analysis import load_trajectory

    monkeypatch.setitem(sys.modules, "mdtraj", None)
    monkeypatch.setitem(sys.modules, "mdtraj.formats", None)
    with pytest.raises(ImportError, match=r"pip install 'jaxabc\[water\]'"):
        load_trajectory(tmp_path / "traj.xtc")
