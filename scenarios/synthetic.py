"""The paper's synthetic scenario: a 1-D point mass regulated by LQR with theta = q / r drawn from a mixture.

Defaults follow the paper: two Gaussian kernels on theta (mu_1 = 4, sigma_1 = 1; mu_2 = 0.4, sigma_2 = 0.1, the
caption's swapped mu_1 corrected), draws kept positive, 2,000 trajectories split 1,800 / 200. What the paper
leaves open is stated here: dt = 0.1 s, N = 50 steps, equal kernel weights, regulation to the origin from one
start state x_0 = (1 m, 0 m/s). With that single start the paper's magnitudes come back (see README); start
states drawn from ranges (``position_range``, ``velocity_range``) make the features depend on the start as much
as on theta, which is a harder, different problem.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pirl_sim.features import lqr_features
from pirl_sim.model import DriverModel, synthetic_model
from pirl_sim.population import Population, Style, generate_demonstrations
from pirl_sim.trajectory import Trajectory

__all__ = ["SyntheticConfig", "SyntheticData", "PAPER_STYLES", "generate"]

#: largest n_trajectories [trajectories]: the data set is held in memory
MAX_TRAJECTORIES = 10**6
#: largest n_steps [steps] per trajectory
MAX_STEPS = 10**5
#: largest |start position| [m] and |start velocity| [m/s]: beyond, the quadratic features overflow
MAX_START = 1e6

PAPER_STYLES = (
    Style("kernel 1 (mu=4, sigma=1)", 0.5, {"state_sq": 4.0}, {"state_sq": 1.0}),
    Style("kernel 2 (mu=0.4, sigma=0.1)", 0.5, {"state_sq": 0.4}, {"state_sq": 0.1}),
)


@dataclass(frozen=True)
class SyntheticConfig:
    """Parameters of the synthetic data set (defaults: the paper's).

    Attributes
    ----------
    n_trajectories, n_train : int          total and training counts (the rest is the test set)
    n_steps : int                          N
    dt : float                             [s]
    position_range : (float, float)        start positions [m]
    velocity_range : (float, float)        start velocities [m/s]
    styles : tuple of Style                mixture over theta (feature names: state_sq, control_sq)
    rationality : float or None            None: exact LQR optima; beta: Boltzmann-rational demos
    seed : int
    """

    n_trajectories: int = field(default=2000, metadata={"doc": "trajectories in all (train + test)"})
    n_train: int = field(default=1800, metadata={"doc": "training trajectories; the rest are the test set"})
    n_steps: int = field(default=50, metadata={"doc": "steps N per trajectory"})
    dt: float = field(default=0.1, metadata={"doc": "step [s]"})
    position_range: tuple[float, float] = field(
        default=(1.0, 1.0), metadata={"doc": "start positions [m], drawn uniformly"})
    velocity_range: tuple[float, float] = field(
        default=(0.0, 0.0), metadata={"doc": "start velocities [m/s], drawn uniformly"})
    styles: tuple[Style, ...] = field(
        default=PAPER_STYLES, metadata={"doc": "styles over (state_sq, control_sq); default: the paper's two kernels"})
    rationality: float | None = field(
        default=None, metadata={"doc": "Boltzmann beta; inf: exact LQR optima (the paper's)"})
    seed: int = 0

    def __post_init__(self) -> None:
        for name in ("n_trajectories", "n_train", "n_steps", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise TypeError(f"{name} must be an integer, got {v!r}")
        if not 2 <= self.n_trajectories <= MAX_TRAJECTORIES:
            raise ValueError(f"n_trajectories must be in [2, {MAX_TRAJECTORIES}], got {self.n_trajectories}")
        if not 1 <= self.n_train < self.n_trajectories:
            raise ValueError(f"n_train must be in [1, n_trajectories - 1] = [1, {self.n_trajectories - 1}], got {self.n_train}")
        if not 2 <= self.n_steps <= MAX_STEPS:
            raise ValueError(f"n_steps must be in [2, {MAX_STEPS}], got {self.n_steps}")
        if not np.isfinite(self.dt) or self.dt <= 0:
            raise ValueError(f"dt must be > 0 s, got {self.dt!r}")
        for name in ("position_range", "velocity_range"):
            lo, hi = getattr(self, name)
            if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
                raise ValueError(f"{name} must be (low, high) with low <= high, got {(lo, hi)}")
            if max(abs(lo), abs(hi)) > MAX_START:
                raise ValueError(f"{name} must lie within [-{MAX_START:g}, {MAX_START:g}], got {(lo, hi)}")

    def model(self) -> DriverModel:
        return synthetic_model(self.dt)

    def population(self) -> Population:
        return Population(lqr_features(), self.styles, self.rationality)


@dataclass(frozen=True)
class SyntheticData:
    config: SyntheticConfig
    model: DriverModel
    train: list[Trajectory]
    test: list[Trajectory]


def generate(config: SyntheticConfig = SyntheticConfig()) -> SyntheticData:
    """Draw the data set; same config (seed included), same bytes."""
    rng = np.random.default_rng(config.seed)
    model = config.model()
    n = config.n_trajectories
    x0 = np.column_stack([rng.uniform(*config.position_range, n), rng.uniform(*config.velocity_range, n)])
    demos = generate_demonstrations(model, config.population(), x0, config.n_steps, rng)
    order = rng.permutation(n)
    train = [demos[i] for i in order[: config.n_train]]
    test = [demos[i] for i in order[config.n_train :]]
    return SyntheticData(config, model, train, test)
