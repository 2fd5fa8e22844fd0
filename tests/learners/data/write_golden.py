"""Write the golden model files of one revision of pirl_sim (run with that revision on the import path).

Usage: python3 write_golden.py OUT_DIR TAG

Fits small learners on the synthetic data set (60 trajectories, 48 for training, seed 5), saves each with that
revision's ``save`` as ``TAG_<learner>.npz`` and writes ``TAG_expected.npz``: the first 10 steps of the 12 test
trajectories (``hist_states``, ``hist_controls``, ``dt``) and, per learner, what that revision inferred and
predicted from them (``<learner>.theta``, ``<learner>.states`` over 8 steps, ``<learner>.style``).
Only APIs present in every revision since model files exist are used.
"""

import sys
import warnings
from pathlib import Path

import numpy as np

from pirl_sim.learners import PIRLDPGMM, PIRLGMM, PIRLKNN, TIRL
from pirl_sim.scenarios.synthetic import SyntheticConfig, generate

LEARNERS = {
    "tirl": (TIRL, {}),
    "pirl-gmm": (PIRLGMM, {"n_components": 2, "random_state": 0}),
    "pirl-dpgmm": (PIRLDPGMM, {"max_components": 4, "random_state": 0}),
    "pirl-knn": (PIRLKNN, {"n_neighbors": 3}),
    "pirl-knn-window": (PIRLKNN, {"n_neighbors": 2, "window": 10, "windows": "first", "average": "linear"}),
}


def main(out: Path, tag: str) -> None:
    out.mkdir(parents=True, exist_ok=True)
    data = generate(SyntheticConfig(n_trajectories=60, n_train=48, seed=5))
    hist = [t.window(0, 10) for t in data.test]
    expected = {"hist_states": np.stack([h.states for h in hist]),
                "hist_controls": np.stack([h.controls for h in hist]), "dt": np.array(hist[0].dt)}
    for name, (cls, params) in LEARNERS.items():
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            learner = cls(**params).fit(data.train)
        learner.save(out / f"{tag}_{name}.npz")
        expected[f"{name}.theta"] = learner.infer_weights(hist)
        expected[f"{name}.states"] = learner.predict_states(hist, 8)
        if hasattr(learner, "predict_style"):
            expected[f"{name}.style"] = np.asarray(learner.predict_style(hist))
    np.savez(out / f"{tag}_expected.npz", **expected)


if __name__ == "__main__":
    main(Path(sys.argv[1]), sys.argv[2])
