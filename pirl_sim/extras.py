"""The optional parts of the install (pip extras): which extra brings an optional module, and how to install it.

One place for the wording every "not installed" message uses, so a user reads the same command wherever a
missing simulator, map reader, cluster client or RL library stops them.
"""

from __future__ import annotations

__all__ = ["EXTRAS", "extra_of", "install_hint"]

#: the extra (``pyproject.toml``'s ``[project.optional-dependencies]``) that installs each optional top-level module
EXTRAS = {"sumolib": "sumo", "traci": "sumo", "libsumo": "sumo", "highway_env": "highway", "gymnasium": "highway",
          "lanelet2": "maps", "dask": "dask", "distributed": "dask", "stable_baselines3": "rl", "torch": "rl"}


def extra_of(module: str | None) -> str | None:
    """The extra that installs ``module`` (a dotted name; its top-level package counts), or None for a module
    that is not an optional one of ours."""
    return EXTRAS.get((module or "").split(".")[0])


def install_hint(extra: str) -> str:
    """How to install ``extra``: ``"install the 'sumo' extra: pip install 'pirl_sim[sumo]' (...)"``."""
    if extra not in set(EXTRAS.values()):
        raise ValueError(f"unknown extra {extra!r}; extras: {', '.join(sorted(set(EXTRAS.values())))}")
    return f"install the '{extra}' extra: pip install 'pirl_sim[{extra}]' (pip install -e '.[{extra}]' in a checkout)"
