"""The install hints: every extra a hint names is one pyproject.toml declares."""

import tomllib
from pathlib import Path

import pytest

from pirl_sim.extras import EXTRAS, extra_of, install_hint

ROOT = Path(__file__).resolve().parents[2]


def test_every_extra_named_is_declared():
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    assert set(EXTRAS.values()) <= set(declared)


def test_hint_names_the_extra_and_a_submodule_counts():
    assert extra_of("sumolib.net") == "sumo" and extra_of("numpy") is None and extra_of(None) is None
    assert "pip install 'pirl_sim[maps]'" in install_hint("maps")


def test_unknown_extra_is_refused():
    with pytest.raises(ValueError, match="unknown extra 'gpu'; extras: dask, highway, maps, rl, sumo"):
        install_hint("gpu")
