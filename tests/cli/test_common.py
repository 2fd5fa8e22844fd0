"""What the commands share (pirl_sim.cli.common): durations in seconds to model steps, none clamped silently."""

import pytest

from pirl_sim.cli.common import seconds_to_steps


@pytest.mark.parametrize("seconds", [-5.0, 0.0, -3, float("nan"), float("inf"), 0.09, True, "2"])
def test_seconds_to_steps_rejects_what_would_be_clamped(seconds):
    with pytest.raises(ValueError, match="--history"):
        seconds_to_steps(seconds, 0.2, "--history")


def test_seconds_to_steps_rounds_to_steps():
    assert seconds_to_steps(2.0, 0.2, "--history") == 10 and seconds_to_steps(0.15, 0.2, "--horizon") == 1
