"""A recorded scene for replay tests: cars weaving along one straight lane (INTERACTION track file and
Lanelet2 map)."""

import numpy as np
import pandas as pd


def weaving_scene(tmp_path, n_tracks=12):
    """Straight lane; every car weaves across it the same way along x (a route-consistent driven path)."""
    from pirl_sim.io.interaction import write_tracks
    from pirl_sim.io.lanelet2_map import write_map

    x = np.linspace(0.0, 400.0, 41)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows, frame = [], 1
    for i in range(n_tracks):
        n = 200
        frames = np.arange(frame, frame + n)
        speed = 8.0 + 0.3 * i
        xx = 10.0 + 3.0 * i + speed * 0.1 * np.arange(n)
        y = 1.2 * np.sin(xx / 15.0) + 0.1 * (i % 3 - 1)
        psi = np.arctan(1.2 / 15.0 * np.cos(xx / 15.0))
        rows.append(pd.DataFrame({"track_id": i + 1, "frame_id": frames, "timestamp_ms": 100 * frames,
                                  "agent_type": "car", "x": xx, "y": y, "vx": speed, "vy": 0.0, "psi_rad": psi,
                                  "length": 4.5, "width": 1.8}))
        frame += n + 10
    write_tracks(pd.concat(rows, ignore_index=True), tmp_path / "vehicle_tracks_000.csv")
    return tmp_path / "vehicle_tracks_000.csv", tmp_path / "map.osm"
