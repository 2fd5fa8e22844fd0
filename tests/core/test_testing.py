"""pirl_sim.testing.assert_recovered: it passes within the tolerances, lists every miss and checks its arguments."""

import numpy as np
import pytest

from pirl_sim.testing import assert_recovered, recovery_misses

from recovery_reports import error_report


def test_assert_recovered_passes_and_lists_every_miss():
    err = np.column_stack([np.full(10, 0.01), np.r_[np.full(5, 0.01), np.full(5, 0.3)]])
    rep = error_report(err, styles=["calm"] * 5 + ["eager"] * 5)
    assert_recovered(rep, {"speed_dev": 0.02})
    assert_recovered(rep, {"*": 0.4}, statistic="p90", styles="each", bound="high")
    with pytest.raises(AssertionError) as exc:
        assert_recovered(rep, {"median": {"*": 0.05}, "p90": {"speed_dev": 0.05}}, styles="each")
    text = str(exc.value)
    assert "1 figure(s) out of tolerance" not in text
    assert "acc_sq, style 'eager' (n=5): median |log error| 0.3" in text
    assert "tolerance 0.05" in text and "speed_dev" not in text.split("out of tolerance:")[1]
    misses = recovery_misses(rep, {"acc_sq": 0.05}, styles="each")
    assert [(m.feature, m.style) for m in misses] == [("acc_sq", "all"), ("acc_sq", "eager")]
    # the upper end of the interval is stricter than the estimate
    assert not recovery_misses(rep, {"speed_dev": 0.01}) and recovery_misses(rep, {"speed_dev": 0.0099})


@pytest.mark.parametrize("kwargs, error, match", [
    ({"tolerances": {"jerk_sq": 0.1}}, ValueError, r"unknown feature 'jerk_sq'.*speed_dev"),
    ({"tolerances": {"speed_dev": -1.0}}, ValueError, r"tolerance of 'speed_dev'.*>= 0.*-1.0"),
    ({"tolerances": {"max": {"speed_dev": 0.1}}}, ValueError, r"statistic must be one of .*'max'"),
    ({"tolerances": {"speed_dev": 0.1}, "styles": ["fast"]}, ValueError, r"\['fast'\].*styles are"),
    ({"tolerances": {"speed_dev": 0.1}, "bound": "low"}, ValueError, r"bound must be one of .*'low'"),
    ({"tolerances": {}}, TypeError, r"non-empty mapping"),
    ({"tolerances": {"speed_dev": 0.1, "p90": {"acc_sq": 0.1}}}, TypeError, r"not mixed"),
])
def test_assert_recovered_rejects_bad_arguments(kwargs, error, match):
    rep = error_report(np.full((4, 2), 0.01))
    with pytest.raises(error, match=match):
        assert_recovered(rep, **kwargs)
