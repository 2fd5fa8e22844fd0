import numpy as np
import pytest

from pirl_sim.model import synthetic_model


@pytest.fixture
def model():
    return synthetic_model(0.1)


@pytest.fixture
def rng():
    return np.random.default_rng(12345)
