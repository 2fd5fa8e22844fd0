"""The realism score: box distances, per-vehicle features on hand-made scenes, likelihoods that rank a source
drawn like the reference above a shifted one, the command and its bad inputs."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest

from pirl_sim.evaluation.realism import (FEATURES, OVERLAP_COLUMNS, FeatureSpec, TrackFeatures, box_distance,
                                         compare_sources, overlap_map, realism_figure, score_realism, track_features)


def _box(cx, cy, psi=0.0, length=4.0, width=2.0):
    c, s = math.cos(psi), math.sin(psi)
    pts = [(length / 2, width / 2), (-length / 2, width / 2), (-length / 2, -width / 2), (length / 2, -width / 2)]
    return np.array([[cx + a * c - b * s, cy + a * s + b * c] for a, b in pts])


def test_box_distance_by_hand():
    a = np.stack([_box(0, 0)] * 5)
    b = np.stack([_box(6, 0), _box(3, 0), _box(0, 4, psi=math.pi / 2), _box(5, 4), _box(0, 0, psi=0.3)])
    d = box_distance(a, b)
    assert d == pytest.approx([2.0, 0.0, 1.0, math.sqrt(5.0), 0.0])
    assert box_distance(b, a) == pytest.approx(d)


def _scene(rows):
    """Rows (track_id, frame_id, x, y, vx, vy) -> an INTERACTION table, 0.1 s frames, 4 m x 2 m cars."""
    df = pd.DataFrame(rows, columns=["track_id", "frame_id", "x", "y", "vx", "vy"])
    df["timestamp_ms"] = df["frame_id"] * 100
    df["agent_type"] = "car"
    df["psi_rad"] = np.arctan2(df["vy"], df["vx"])
    df["length"], df["width"] = 4.0, 2.0
    return df


def test_leader_gap_headway_time_to_collision_and_nearest():
    frames = range(1, 11)
    rows = [(1, f, 0.0 + 1.0 * f, 0.0, 10.0, 0.0) for f in frames] + [(2, f, 20.0 + 0.5 * f, 0.0, 5.0, 0.0)
                                                                         for f in frames]
    feats = track_features(_scene(rows))
    g0 = 20.0 - 4.0  # frame 0 spacing minus the half lengths
    follower_gap = feats.values["gap"][0]
    assert follower_gap[0] == pytest.approx(g0 - 0.5)  # frame 1: 20.5 - 1.0 - 4
    assert np.all(np.diff(follower_gap) == pytest.approx(-0.5))
    assert feats.values["time_headway"][0] == pytest.approx(follower_gap / 10.0)
    assert feats.values["time_to_collision"][0] == pytest.approx(np.minimum(follower_gap / 5.0, 5.0))
    assert len(feats.values["gap"][1]) == 0  # the leader has nobody ahead
    assert feats.values["time_to_collision"][1] == pytest.approx(np.full(10, 5.0))
    assert feats.values["nearest_distance"][0] == pytest.approx(follower_gap)
    assert feats.values["acceleration"][0] == pytest.approx(np.zeros(10), abs=1e-9)
    assert feats.values["collision"][0][0] == 0.0
    assert feats.values["stopped_time"][0][0] == 0.0
    assert "lane_offset" not in feats.values  # no map


def test_overlap_is_a_collision_and_opposite_traffic_is_no_leader():
    rows = [(1, f, f * 0.1, 0.0, 1.0, 0.0) for f in range(1, 6)] + [(2, f, 3.0, 0.5, 0.0, 0.0) for f in range(1, 6)]
    rows += [(3, f, 30.0 - f, 0.0, -10.0, 0.0) for f in range(1, 6)]
    feats = track_features(_scene(rows))
    assert [feats.values["collision"][k][0] for k in range(3)] == [1.0, 1.0, 0.0]
    assert feats.values["gap"][0] == pytest.approx(np.zeros(5))  # its leader overlaps it
    assert len(feats.values["gap"][2]) == 0  # the others are ahead of it but head the other way
    assert feats.values["stopped_time"][1][0] == pytest.approx(0.5)  # five 0.1 s steps at rest


def test_overlapping_pairs_are_listed_once_with_where_and_how_long():
    # vehicle 2 stands across vehicle 1's lane; 1 drives through it at 5 m/s: its 4 m box overlaps 2's for the
    # frames in which their centres are less than (4 + 2) / 2 = 3 m apart along x; vehicle 3 is far away
    rows = [(2, f, 10.0, 0.0, 0.0, 0.0) for f in range(1, 31)]
    rows += [(1, f, 0.5 * f + 0.2, 0.0, 5.0, 0.0) for f in range(1, 31)]
    rows += [(3, f, 0.5 * f, 40.0, 5.0, 0.0) for f in range(1, 31)]
    scene = _scene(rows)
    scene.loc[scene["track_id"] == 2, "psi_rad"] = math.pi / 2  # crosswise
    table = track_features(scene).overlaps
    assert tuple(table.columns) == OVERLAP_COLUMNS
    assert len(table) == 1
    row = table.iloc[0]
    assert (row["track_a"], row["track_b"]) == (1, 2)
    inside = [f for f in range(1, 31) if abs(0.5 * f + 0.2 - 10.0) < 3.0]  # boxes 4 x 2 m: 2 + 1 m along x
    assert row["frame_id"] == inside[0] and row["frames"] == len(inside)
    assert row["x"] == pytest.approx((0.5 * inside[0] + 0.2 + 10.0) / 2) and row["y"] == pytest.approx(0.0)
    assert row["heading_difference_deg"] == pytest.approx(90.0)
    assert (row["speed_a"], row["speed_b"]) == pytest.approx((5.0, 0.0))
    apart = track_features(scene[scene["track_id"] != 2]).overlaps
    assert len(apart) == 0 and tuple(apart.columns) == OVERLAP_COLUMNS
    both = TrackFeatures.combine([track_features(scene), track_features(scene)]).overlaps
    assert both["part"].tolist() == [0, 1]


def test_overlap_map_draws_each_source_and_needs_something_to_draw(tmp_path):
    table = pd.DataFrame({"x": [1.0, 2.0], "y": [0.0, 1.0]})
    fig = overlap_map({"a": table, "b": table.iloc[:1]}, tmp_path / "o.png", title="t")
    assert (tmp_path / "o.png").is_file()
    assert [t.get_text() for t in fig.axes[0].get_legend().get_texts()] == ["a (2 pairs)", "b (1 pairs)"]
    with pytest.raises(ValueError, match="nothing to draw"):
        overlap_map({"a": table.iloc[:0]}, tmp_path / "none.png")


def _traffic(rng, n_vehicles, mean_speed, spread=1.0, frames=60):
    """Two lanes of cars at constant speeds drawn around ``mean_speed``, spaced 30 m."""
    rows = []
    for k in range(n_vehicles):
        v = max(rng.normal(mean_speed, spread), 0.5)
        y = 3.5 * (k % 2)
        x0 = 30.0 * (k // 2)
        rows += [(k + 1, f, x0 + v * 0.1 * f, y, v, 0.0) for f in range(1, frames + 1)]
    return _scene(rows)


def test_a_source_like_the_reference_scores_above_a_shifted_one():
    rng = np.random.default_rng(0)
    reference = track_features(_traffic(rng, 30, 8.0))
    same = [track_features(_traffic(rng, 30, 8.0)) for _ in range(3)]
    fast = [track_features(_traffic(rng, 30, 12.0)) for _ in range(3)]
    summary, table = compare_sources(reference, {"same": same, "fast": fast})
    meta = dict(zip(summary["source"], summary["meta_metric"]))
    assert meta["same"] > meta["fast"]
    speed = table[table["feature"] == "speed"].groupby("source")[["likelihood", "wasserstein"]].mean()
    assert speed.loc["same", "likelihood"] > 2 * speed.loc["fast", "likelihood"]
    assert speed.loc["fast", "wasserstein"] == pytest.approx(4.0, abs=1.0)
    assert summary["rollouts"].tolist() == [3, 3] and np.all(np.isfinite(summary["ci95"]))
    weights = table[table["rollout"] == 0].groupby("source")["weight"].sum()
    assert weights.to_numpy() == pytest.approx([1.0, 1.0])  # normalised over the scored features


def test_score_is_deterministic_and_likelihoods_lie_in_the_unit_interval():
    rng = np.random.default_rng(1)
    a, b = track_features(_traffic(rng, 20, 8.0)), track_features(_traffic(rng, 20, 9.0))
    s1, s2 = score_realism(a, b), score_realism(a, b)
    pd.testing.assert_frame_equal(s1.table, s2.table)
    scored = s1.table.dropna(subset=["likelihood"])
    assert ((scored["likelihood"] > 0) & (scored["likelihood"] <= 1)).all()
    assert 0 < s1.meta_metric <= 1
    only_speed = score_realism(a, b, weights={n.name: 0.0 for n in FEATURES if n.name != "speed"})
    assert only_speed.meta_metric == pytest.approx(float(s1.table.set_index("feature").loc["speed", "likelihood"]))


def test_lane_offset_with_a_map(tmp_path):
    from pirl_sim.io.lanelet2_map import load_map, write_map

    x = np.linspace(-10.0, 200.0, 50)
    write_map({"A": np.column_stack([x, np.zeros_like(x)])}, {}, tmp_path / "map.osm")
    rows = [(1, f, f * 1.0, 0.0, 10.0, 0.0) for f in range(1, 6)] + [(2, f, f * 1.0, 1.2, 10.0, 0.0)
                                                                     for f in range(1, 6)]
    feats = track_features(_scene(rows), load_map(tmp_path / "map.osm"))
    assert feats.values["lane_offset"][0] == pytest.approx(np.zeros(5), abs=1e-6)
    assert feats.values["lane_offset"][1] == pytest.approx(np.full(5, 1.2), abs=1e-6)


def test_bad_inputs_name_what_is_wrong():
    with pytest.raises(ValueError, match="bins"):
        FeatureSpec("x", "m", 0.0, 1.0, 1, 0.1)
    with pytest.raises(ValueError, match="low"):
        FeatureSpec("x", "m", 1.0, 1.0, 4, 0.1)
    with pytest.raises(ValueError, match="per"):
        FeatureSpec("x", "m", 0.0, 1.0, 4, 0.1, per="track")
    with pytest.raises(TypeError, match="DataFrame"):
        track_features({"x": [1.0]})
    with pytest.raises(ValueError, match="length"):
        track_features(_scene([(1, 1, 0.0, 0.0, 1.0, 0.0)]).drop(columns=["length"]))
    bad = _scene([(1, 1, 0.0, 0.0, 1.0, 0.0), (1, 2, np.nan, 0.0, 1.0, 0.0)])
    with pytest.raises(ValueError, match="'x'.*non-finite"):
        track_features(bad)
    a = track_features(_traffic(np.random.default_rng(2), 4, 8.0))
    with pytest.raises(ValueError, match="unknown features.*'speeed'"):
        score_realism(a, a, weights={"speeed": 1.0})
    with pytest.raises(ValueError, match="pseudocount"):
        score_realism(a, a, pseudocount=0.0)
    with pytest.raises(ValueError, match="nothing to score"):
        score_realism(a, a, weights={f.name: 0.0 for f in FEATURES})
    with pytest.raises(TypeError, match="TrackFeatures"):
        score_realism(a, "b")
    with pytest.raises(ValueError, match="no TrackFeatures"):
        TrackFeatures.combine([])


def _write(df, path):
    from pirl_sim.io.interaction import write_tracks

    cols = ["track_id", "frame_id", "timestamp_ms", "agent_type", "x", "y", "vx", "vy", "psi_rad", "length", "width"]
    write_tracks(df[cols], path)
    return path


def test_command_writes_the_tables_and_a_figure(tmp_path, capsys):
    from pirl_sim.cli import main

    rng = np.random.default_rng(3)
    ref = _write(_traffic(rng, 20, 8.0), tmp_path / "vehicle_tracks_000.csv")
    same = [_write(_traffic(rng, 20, 8.0), tmp_path / f"same_{k}.csv") for k in range(2)]
    fast = [_write(_traffic(rng, 20, 12.0), tmp_path / f"fast_{k}.csv") for k in range(2)]
    out = tmp_path / "out"
    assert main(["realism", "--reference", str(ref), "--source", "same=" + ",".join(map(str, same)),
                 "--source", "fast=" + ",".join(map(str, fast)), "--out", str(out)]) == 0
    summary = pd.read_csv(out / "summary.csv")
    assert summary["source"].tolist() == ["same", "fast"]
    assert summary["meta_metric"].iloc[0] > summary["meta_metric"].iloc[1]
    assert set(pd.read_csv(out / "features.csv")["feature"]) == {f.name for f in FEATURES if not f.needs_map}
    from matplotlib.image import imread

    img = imread(out / "realism.png")
    grey = np.all(np.abs(img[..., :3] - 0.75) < 0.01, axis=-1)  # the reference's filled histograms
    assert grey.sum() > 500
    printed = capsys.readouterr().out
    assert "meta_metric" in printed
    assert "overlap (all rollouts): reference 0, same 0, fast 0" in printed  # two lanes 3.5 m apart, 30 m gaps
    assert pd.read_csv(out / "overlaps.csv").columns.tolist() == ["source", "rollout", "part", *OVERLAP_COLUMNS]
    assert not (out / "overlaps.png").exists()  # no map and no pair: nothing to draw

    assert main(["realism", "--reference", str(ref), "--source", f"a={same[0]}", "--source", f"a={fast[0]}",
                 "--out", str(out)]) == 2
    assert "repeated: ['a']" in capsys.readouterr().err
    assert main(["realism", "--reference", str(tmp_path / "none.csv"), "--source", f"a={same[0]}",
                 "--out", str(out)]) == 2
    assert "none.csv" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(["realism", "--reference", str(ref), "--source", "nolabel"])
    assert "LABEL=PATH" in capsys.readouterr().err


def test_figure_has_a_panel_per_feature(tmp_path):
    a = track_features(_traffic(np.random.default_rng(4), 6, 8.0))
    fig = realism_figure(a, {"a": [a]}, tmp_path / "r.png")
    assert sum(ax.get_visible() for ax in fig.axes) == len(a.values)
    assert (tmp_path / "r.png").is_file()


def test_command_simulates_a_scenario_source_and_resumes(tmp_path, capsys):
    """``--scenario LABEL=TOML`` runs a SUMO scenario, ``--highway-scenario`` the same file on highway-env, for --seeds
    seeds under OUT/runs and scores them; a rerun keeps the finished runs (nothing simulated again, the same scores)."""
    pytest.importorskip("libsumo")
    pytest.importorskip("highway_env")
    from pirl_sim.cli import main

    ref = _write(_traffic(np.random.default_rng(5), 10, 8.0), tmp_path / "vehicle_tracks_000.csv")
    scenario = tmp_path / "small.toml"
    scenario.write_text("[population]\nn_vehicles = 4\ndepart_interval = 3.0\n")
    out = tmp_path / "out"
    argv = ["realism", "--reference", str(ref), "--scenario", f"small={scenario}", "--highway-scenario",
            f"small-hw={scenario}", "--seeds", "2", "--out", str(out)]
    assert main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("small: simulating seed") == 2 and printed.count("small-hw: simulating seed") == 2
    runs = [out / "runs" / label / f"seed_{s}" / "run.json" for label in ("small", "small-hw") for s in (0, 1)]
    assert [json.loads(r.read_text())["simulator"] for r in runs] == ["sumo"] * 2 + ["highway-env"] * 2
    stamps = [r.stat().st_mtime_ns for r in runs]
    summary = pd.read_csv(out / "summary.csv")
    assert summary["source"].tolist() == ["small", "small-hw"] and summary["rollouts"].tolist() == [2, 2]
    assert main(argv) == 0
    assert "simulating" not in capsys.readouterr().out
    assert [r.stat().st_mtime_ns for r in runs] == stamps
    pd.testing.assert_frame_equal(pd.read_csv(out / "summary.csv"), summary)

    assert main(["realism", "--reference", str(ref), "--out", str(out)]) == 2
    assert "nothing to score" in capsys.readouterr().err
    assert main(["realism", "--reference", str(ref), "--source", f"small={ref}", "--scenario", f"small={scenario}",
                 "--out", str(out)]) == 2
    assert "repeated: ['small']" in capsys.readouterr().err
    assert main(["realism", "--reference", str(ref), "--scenario", f"x={tmp_path / 'none.toml'}",
                 "--out", str(out)]) == 2
    assert "none.toml" in capsys.readouterr().err
    for bad in (["--scenario", "x"], ["--highway-scenario", "x"], ["--scenario", f"x={scenario}", "--seeds", "0"]):
        with pytest.raises(SystemExit):
            main(["realism", "--reference", str(ref), *bad])
        assert "expected" in capsys.readouterr().err


def test_entry_wait_and_accepted_gap_on_a_roundabout_map(tmp_path):
    """A car waits 3 s on an entry lane and enters the ring while a ring car 13.7 m upstream closes in at 9.4 m/s:
    its entry wait is 3 s and its accepted gap that time; a car that starts on the ring has neither."""
    from pirl_sim.io.lanelet2_map import load_map, write_map

    def arc(a0, a1):
        a = np.radians(np.linspace(a0, a1, 20))
        return np.column_stack([20 * np.cos(a), 20 * np.sin(a)])

    lanes = {"E": np.array([[0.0, -60.0], [0.0, -20.0]]), "R1": arc(-90, 0), "R2": arc(0, 90), "R3": arc(90, 180),
             "R4": arc(180, 270)}
    write_map(lanes, {"E": ["R1"], "R1": ["R2"], "R2": ["R3"], "R3": ["R4"], "R4": ["R1"]}, tmp_path / "map.osm")
    entering = ([(1, f, 0.0, -50.0 + f, 0.0, 10.0) for f in range(1, 21)]
                + [(1, f, 0.0, -30.0, 0.0, 0.0) for f in range(21, 51)]
                + [(1, f, 0.0, -30.0 + (f - 50), 0.0, 10.0) for f in range(51, 60)])  # to 1 m before the ring
    entry = 20 * np.array([np.cos(np.radians(-80)), np.sin(np.radians(-80))])
    entering.append((1, 60, *entry, 10.0, 1.8))
    theta = np.radians(-120)
    ring_xy, ring_v = 20 * np.array([np.cos(theta), np.sin(theta)]), 10 * np.array([-np.sin(theta), np.cos(theta)])
    ringcar = [(2, f, *(ring_xy + (f - 60) * 0.1 * ring_v), *ring_v) for f in range(58, 63)]
    on_ring = [(3, f, *arc(0, 90)[f - 1], -10.0, 10.0) for f in range(1, 6)]
    feats = track_features(_scene(entering + ringcar + on_ring), load_map(tmp_path / "map.osm"))
    rel = entry - ring_xy
    gap = np.hypot(*rel) / (ring_v @ rel / np.hypot(*rel))
    assert feats.values["entry_wait"][0] == pytest.approx([3.0])
    assert feats.values["accepted_gap"][0] == pytest.approx([gap]) and 1.0 < gap < 2.0
    assert [len(feats.values[n][i]) for n in ("entry_wait", "accepted_gap") for i in (1, 2)] == [0, 0, 0, 0]
