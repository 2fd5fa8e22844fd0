"""Learners of driving costs: TIRL, PIRL-GMM, PIRL-DPGMM, PIRL-kNN (scikit-learn conventions)."""

from .base import BaseLearner
from .gmm import PIRLDPGMM, PIRLGMM
from .knn import PIRLKNN
from .model_io import SavableLearner, load_learner, save_learner
from .tirl import TIRL

__all__ = ["BaseLearner", "SavableLearner", "TIRL", "PIRLGMM", "PIRLDPGMM", "PIRLKNN", "LEARNERS", "make_learner",
           "load_learner", "save_learner"]

LEARNERS = {"tirl": TIRL, "pirl-gmm": PIRLGMM, "pirl-dpgmm": PIRLDPGMM, "pirl-knn": PIRLKNN}


def make_learner(name: str, **params) -> BaseLearner:
    """A learner by name (one of `LEARNERS`), with its parameters."""
    if name not in LEARNERS:
        raise ValueError(f"unknown learner {name!r}; choose one of {sorted(LEARNERS)}")
    return LEARNERS[name](**params)
