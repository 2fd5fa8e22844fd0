"""Scores (pirl_sim.metrics): MED as the paper defines it, the recovery and clustering metrics, and the multi-modal
minADE_K / minFDE_K / miss rate as the INTERACTION challenge defines them, and the mixture NLL."""

import numpy as np
import pytest

from pirl_sim.metrics import (
    ade_fde,
    adjusted_rand_index,
    interaction_longitudinal_threshold,
    interaction_miss,
    match_styles,
    med,
    min_ade,
    min_fde,
    mixture_nll,
    weight_recovery_error,
)


# ---------------------------------------------------------------------------------------------- metrics
def _two_futures():
    """One case, 3 steps in 2-D: the truth along x at 1 m/step; future 0 is 1 m to the left all along, future 1
    exact but for 2 m ahead at the last step."""
    truth = np.array([[[1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]])
    f0 = truth[0] + [0.0, 1.0]
    f1 = truth[0] + [[0.0, 0.0], [0.0, 0.0], [2.0, 0.0]]
    return np.stack([f0, f1])[None], truth


def test_min_ade_and_min_fde_by_hand():
    futures, truth = _two_futures()
    np.testing.assert_allclose(min_ade(futures, truth), [2.0 / 3.0])  # future 1: (0 + 0 + 2) / 3 < future 0: 1
    np.testing.assert_allclose(min_fde(futures, truth), [1.0])  # future 0 ends 1 m off, future 1 2 m
    # K = 1 is the single prediction's ADE / FDE
    np.testing.assert_allclose(min_ade(futures[:, :1], truth), [1.0])
    np.testing.assert_allclose(min_fde(futures[:, 1:], truth), [2.0])


def test_longitudinal_threshold_is_the_challenges_piecewise_rule():
    v = np.array([0.0, 1.4, 6.2, 11.0, 30.0])
    np.testing.assert_allclose(interaction_longitudinal_threshold(v), [1.0, 1.0, 1.5, 2.0, 2.0])


def test_miss_rule_lateral_longitudinal_and_all_futures():
    truth = np.zeros((1, 2, 2))
    truth[0, :, 0] = [0.0, 10.0]  # heading along +x, 10 m/s at the end
    lon_max = 1.0 + (10.0 - 1.4) / (11.0 - 1.4)  # 1.896 m at 10 m/s
    speed, heading = np.array([10.0]), np.array([0.0])

    def miss(offset):  # one future, offset (dx, dy) at the last step
        futures = truth[:, None].copy()
        futures[0, 0, -1] += offset
        return bool(interaction_miss(futures, truth, speed, heading)[0])

    assert not miss([lon_max - 0.01, 0.0]) and miss([lon_max + 0.01, 0.0])  # longitudinal, speed-dependent
    assert not miss([-(lon_max - 0.01), 0.0]) and miss([-(lon_max + 0.01), 0.0])
    assert not miss([0.0, 0.99]) and miss([0.0, 1.01])  # lateral: 1 m whatever the speed
    assert not miss([0.0, 1.0])  # "larger than" the threshold: exactly 1 m is a hit
    # the frame is the true heading's: the same 1.5 m offset along y is longitudinal when the car drives along y
    futures = truth[:, None].copy()
    futures[0, 0, -1] += [0.0, 1.5]
    assert interaction_miss(futures, truth, speed, np.array([0.0]))[0]
    assert not interaction_miss(futures, truth, speed, np.array([np.pi / 2]))[0]
    # a case misses only when every future misses
    two = np.concatenate([futures, truth[:, None]], axis=1)
    assert not interaction_miss(two, truth, speed, np.array([0.0]))[0]
    # slow car: 1 m longitudinal threshold
    assert interaction_miss(futures, truth, np.array([1.0]), np.array([np.pi / 2]))[0]
    # 1-D positions: the whole error is longitudinal, no heading needed
    line = np.array([[[0.0], [5.0]]])
    assert interaction_miss(line[:, None] + 1.2, line, np.array([1.0]))[0]
    assert not interaction_miss(line[:, None] + 1.2, line, np.array([11.0]))[0]


def test_mixture_nll_by_hand():
    futures, truth = _two_futures()
    sigma = 0.5
    T, P = 3, 2
    const = T * P * (np.log(sigma) + 0.5 * np.log(2 * np.pi))
    sq = np.array([3.0, 4.0])  # squared errors summed over steps and coordinates
    p = np.array([0.25, 0.75])
    expected = -np.log(np.sum(p * np.exp(-0.5 * sq / sigma**2))) + const
    np.testing.assert_allclose(mixture_nll(futures, p[None], truth, sigma), [expected])
    # a zero-probability future does not count; one exact future at probability 1 gives the constant only
    np.testing.assert_allclose(mixture_nll(futures, [[1.0, 0.0]], truth, sigma), [0.5 * 3.0 / sigma**2 + const])
    np.testing.assert_allclose(mixture_nll(truth[:, None], [[1.0]], truth, sigma), [const])


@pytest.mark.parametrize("call", [min_ade, min_fde])
def test_bad_futures_are_rejected(call):
    futures, truth = _two_futures()
    with pytest.raises(ValueError, match="K >= 1.*K=0"):
        call(futures[:, :0], truth)
    with pytest.raises(ValueError, match=r"true futures must be \(M, T, P\).*got shape \(1, 2, 2\)"):
        call(futures, truth[:, :2])
    with pytest.raises(ValueError, match=r"futures must be \(M cases, K futures.*shape \(2, 3, 2\)"):
        call(futures[0], truth)
    bad = futures.copy()
    bad[0, 1, 2, 0] = np.nan
    with pytest.raises(ValueError, match=r"predicted futures contain 1 non-finite.*\(0, 1, 2, 0\)"):
        call(bad, truth)
    with pytest.raises(ValueError, match="true futures contain 1 non-finite"):
        call(futures, np.where(truth == 3.0, np.nan, truth))


def test_bad_miss_and_nll_inputs_are_rejected():
    futures, truth = _two_futures()
    with pytest.raises(ValueError, match=r"speed must be \(M,\)"):
        interaction_miss(futures, truth, np.array([1.0, 2.0]), np.array([0.0]))
    with pytest.raises(ValueError, match="heading .* is required"):
        interaction_miss(futures, truth, np.array([1.0]))
    with pytest.raises(ValueError, match="speeds contain 1 non-finite"):
        interaction_miss(futures, truth, np.array([np.nan]), np.array([0.0]))
    with pytest.raises(ValueError, match="speeds must be >= 0 m/s, got a minimum of -1.0"):
        interaction_miss(futures, truth, np.array([-1.0]), np.array([0.0]))
    with pytest.raises(ValueError, match="headings contain 1 non-finite"):
        interaction_miss(futures, truth, np.array([1.0]), np.array([np.nan]))
    with pytest.raises(ValueError, match="sum to 1, case 0 sums to 0.9"):
        mixture_nll(futures, [[0.4, 0.5]], truth, 0.5)
    with pytest.raises(ValueError, match=r"proba must be \(M, K\) = \(1, 2\).*got shape \(1, 3\)"):
        mixture_nll(futures, [[0.2, 0.3, 0.5]], truth, 0.5)
    with pytest.raises(ValueError, match="probabilities must be >= 0"):
        mixture_nll(futures, [[-0.5, 1.5]], truth, 0.5)
    with pytest.raises(ValueError, match="probabilities contain 1 non-finite"):
        mixture_nll(futures, [[np.nan, 1.0]], truth, 0.5)
    for sigma in (0.0, -1.0, np.nan, True):
        with pytest.raises(ValueError, match=f"sigma must be .* got {sigma!r}"):
            mixture_nll(futures, [[0.5, 0.5]], truth, sigma)


def test_med_is_the_papers_formula():
    truth = np.zeros((2, 4, 2))
    pred = np.zeros((2, 4, 2))
    pred[0, :, 0] = 3.0
    pred[1, :, 1] = [0.0, 0.0, 0.0, 4.0]
    assert med(pred, truth) == pytest.approx((3.0 + 1.0) / 2)
    # different lengths: each trajectory averaged over its own length first
    assert med([pred[0], pred[1, :2]], [truth[0], truth[1, :2]]) == pytest.approx(1.5)
    ade, fde = ade_fde(pred, truth)
    assert ade == pytest.approx(2.0) and fde == pytest.approx(3.5)
    with pytest.raises(ValueError, match="differ in shape"):
        med(pred, truth[:, :3])
    with pytest.raises(ValueError, match="non-finite"):
        med(np.full((1, 2, 1), np.nan), np.zeros((1, 2, 1)))


def test_recovery_and_clustering_metrics():
    err = weight_recovery_error(np.array([[2.0, 1.0], [0.5, 1.0]]), np.array([[1.0, 1.0], [1.0, 1.0]]), 1)
    np.testing.assert_allclose(err, [np.log(2), np.log(2)])
    assert adjusted_rand_index([0, 0, 1, 1], [1, 1, 0, 0]) == pytest.approx(1.0)
    assert match_styles([0, 0, 1, 1, 2], [5, 5, 7, 7, 7]) == {5: 0, 7: 1}
    with pytest.raises(ValueError, match="positive"):
        weight_recovery_error(np.array([0.0, 1.0]), np.array([1.0, 1.0]), 1)
