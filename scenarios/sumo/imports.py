"""SUMO's Python modules (``sumolib``, ``traci``, ``libsumo``), imported when first needed: a missing one is an
error that names the extra which installs it."""

from __future__ import annotations

import importlib
from types import ModuleType

from pirl_sim.extras import install_hint

__all__ = ["sumo_module", "EXTRA_HINT"]

#: how to install SUMO's modules (the ``sumo`` extra: eclipse-sumo, libsumo, traci, sumolib, numba)
EXTRA_HINT = install_hint("sumo")


def sumo_module(name: str) -> ModuleType:
    """``import name`` (one of SUMO's modules); ModuleNotFoundError naming the ``sumo`` extra when it is missing."""
    try:
        return importlib.import_module(name)
    except ModuleNotFoundError as exc:
        if exc.name is None or exc.name.split(".")[0] != name:
            raise  # a module that SUMO's own code imports: not ours to explain
        raise ModuleNotFoundError(f"{name} is not installed; SUMO scenarios need it: {EXTRA_HINT}",
                                  name=name) from None
