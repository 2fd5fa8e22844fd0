"""The ego's per-frame projection onto its route (envs.common._project_point, scalar) equals RouteSet.project."""

import numpy as np
import pytest

pytest.importorskip("highway_env")

from pirl_sim.envs.common import _project_point  # noqa: E402
from pirl_sim.scenarios.highway.network import RoundaboutGeometry, build_network, route_catalogue, route_set  # noqa: E402


def test_scalar_projection_equals_the_route_sets():
    net = build_network(RoundaboutGeometry(20.0))
    routes = route_set(net, route_catalogue(net))
    rng = np.random.default_rng(0)
    compared = 0
    for r, path in enumerate(routes.paths):
        for _ in range(60):
            s = rng.uniform(-15.0, path.length + 15.0)  # also on the straight extensions
            xy = routes.position(routes.offsets[r] + s, rng.normal(0.0, 1.0))
            guess = s + rng.normal(0.0, 2.0)
            mine = _project_point(path, float(xy[0]), float(xy[1]), guess)
            try:
                theirs = float(routes.project([r], xy[None], [guess])[0])
            except ValueError:
                theirs = None
            assert (mine is None) == (theirs is None)
            if mine is not None:
                assert mine == pytest.approx(theirs, abs=1e-9)
                compared += 1
    assert compared > 100
    assert _project_point(routes.paths[0], 0.0, 0.0, float("nan")) is None
