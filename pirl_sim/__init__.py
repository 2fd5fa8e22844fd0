"""pirl_sim: an evaluation harness for probabilistic inverse reinforcement learning of diverse drivers.

Core types and maths live here (pure array functions, no simulator); learners in `pirl_sim.learners`,
scenarios in `pirl_sim.scenarios`, experiments in `pirl_sim.experiments`.
"""

from .dynamics import LinearDynamics, longitudinal, point_mass
from .features import Feature, FeatureSet, lqr_features, squared_control, squared_state
from .model import DriverModel, synthetic_model
from .population import Population, Style
from .trajectory import Trajectory

from . import envs  # registers pirl_sim/Roundabout-v0 with gymnasium when it is installed

__version__ = "0.1.0"

__all__ = [
    "Trajectory",
    "LinearDynamics",
    "point_mass",
    "longitudinal",
    "Feature",
    "FeatureSet",
    "lqr_features",
    "squared_state",
    "squared_control",
    "DriverModel",
    "synthetic_model",
    "Population",
    "Style",
    "envs",
    "__version__",
]
