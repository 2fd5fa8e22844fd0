"""Styles found back in weight space from per-track fits (`pirl_sim.experiments.recovery_styles`)."""

import numpy as np
import pandas as pd
import pytest

from pirl_sim.experiments import recovery_styles
from pirl_sim.experiments.recovery import IDENTIFIED_SE, MIN_NEAR_STEPS
from pirl_sim.experiments.recovery_styles import UNKNOWN_SE, track_measurements

RULE = {"identified_se": IDENTIFIED_SE, "min_near_steps": MIN_NEAR_STEPS}


def style_mixtures(tracks, features):
    return recovery_styles.style_mixtures(tracks, features, **RULE)

FEATURES = ["speed_dev", "headway"]


def _tracks(rng, n=20, seeds=(0, 1), scramble_headway=0.0):
    """Two styles (log weights (1, 1) and (-1, 3)) with 10 % spread, fitted with small errors; a share
    ``scramble_headway`` of the tracks never came near a vehicle ahead: their headway fit is anywhere and has no
    standard error."""
    rows = []
    for seed in seeds:
        for i in range(n):
            style = i % 2
            true = np.array([1.0, 1.0] if style == 0 else [-1.0, 3.0]) + rng.normal(0, 0.1, 2)
            hat = true + rng.normal(0, 0.01, 2)
            se = [0.01, 0.01]
            steps = 20
            if rng.random() < scramble_headway:
                hat[1], se[1], steps = rng.uniform(-5, 15), np.inf, 0
            rows.append({"simulator": "sumo", "control_noise": 0.0, "seed": seed, "track_id": i,
                         "style_name": ["fast", "careful"][style],
                         "theta_speed_dev": np.exp(true[0]), "theta_hat_speed_dev": np.exp(hat[0]),
                         "se_log_speed_dev": se[0],
                         "theta_headway": np.exp(true[1]), "theta_hat_headway": np.exp(hat[1]),
                         "se_log_headway": se[1], "headway_steps": steps})
    return pd.DataFrame(rows)


def test_styles_come_back_and_unknown_weights_are_integrated_out():
    tracks = _tracks(np.random.default_rng(0), scramble_headway=0.5)
    out = style_mixtures(tracks, FEATURES)
    assert list(out["seed"]) == ["0", "1", "pooled"]
    assert (out["ari"] == 1.0).all()
    assert (out["mean_err_speed_dev"] < 0.1).all() and (out["mean_err_headway"] < 0.15).all()
    # the same data clustered as if the scrambled headway fits were known: the styles are lost
    known = tracks.assign(se_log_headway=0.01, headway_steps=20)
    assert style_mixtures(known, ["headway"])["ari"].max() < 0.9
    pd.testing.assert_frame_equal(style_mixtures(tracks, FEATURES), out)  # same data, same result


def test_unknown_weights_get_a_wide_error():
    tracks = _tracks(np.random.default_rng(1), n=4, seeds=(0,))
    tracks.loc[0, "se_log_headway"] = 0.5           # too large: not identified
    tracks.loc[1, "headway_steps"] = 2              # too few steps within reach
    tracks.loc[2, "se_log_speed_dev"] = np.nan      # written as empty (inf)
    tracks.loc[0, "se_log_speed_dev"] = 0.5         # a free weight: its error as it is
    _, S = track_measurements(tracks, FEATURES, **RULE)
    assert S[0, 1, 1] == S[1, 1, 1] == S[2, 0, 0] == UNKNOWN_SE**2
    assert S[0, 0, 0] == pytest.approx(0.25)
    assert S[3, 0, 0] == S[3, 1, 1] == pytest.approx(0.01**2) and S[3, 0, 1] == 0.0


def test_bad_input_is_named():
    tracks = _tracks(np.random.default_rng(2))
    with pytest.raises(ValueError, match="se_log_yielding"):
        style_mixtures(tracks, ["speed_dev", "yielding"])
    with pytest.raises(ValueError, match="at least one feature"):
        style_mixtures(tracks, [])
