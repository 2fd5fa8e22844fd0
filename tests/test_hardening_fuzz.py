"""Issue 15: property-based fuzz tests of every input format. Whatever the input, the reader either returns what
the file says (checked field by field) or raises ``ValueError`` / ``TypeError`` with a message; never another
exception type, never a silently changed value."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

hypothesis = pytest.importorskip("hypothesis")
from hypothesis import HealthCheck, given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from pirl_sim.io.interaction import VEHICLE_COLUMNS, read_tracks, read_tracks_lenient  # noqa: E402

from shared_sample import SAMPLE_MAP, SAMPLE_TRACKS, needs_sample  # noqa: E402
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])

#: field values a user's file might hold by mistake
ODD_FIELDS = st.sampled_from(["1.5", "nan", "inf", "-inf", "", " ", "abc", "-1", "0", "1e400", "1e3", "+2",
                              "99999999999999999999999", "1_0", "0x10", "car", "\"", "1,2", "NaN", "4.0"])
FIELD = st.one_of(ODD_FIELDS, st.text(max_size=6), st.integers(-10**6, 10**6).map(str),
                  st.floats(allow_nan=True, allow_infinity=True).map(repr))


@st.composite
def mutated_text(draw, base: str, field_sep: str = ","):
    """``base`` with a few random edits: a field replaced, a line deleted, duplicated or swapped, the text cut."""
    lines = base.splitlines()
    for _ in range(draw(st.integers(1, 4))):
        kind = draw(st.sampled_from(["field", "field", "field", "delete", "duplicate", "swap", "cut"]))
        i = draw(st.integers(0, len(lines) - 1))
        if kind == "field":
            fields = lines[i].split(field_sep)
            j = draw(st.integers(0, len(fields) - 1))
            fields[j] = draw(FIELD)
            lines[i] = field_sep.join(fields)
        elif kind == "delete" and len(lines) > 1:
            del lines[i]
        elif kind == "duplicate":
            lines.insert(i, lines[i])
        elif kind == "swap":
            k = draw(st.integers(0, len(lines) - 1))
            lines[i], lines[k] = lines[k], lines[i]
        elif kind == "cut":
            text = "\n".join(lines)
            lines = text[:draw(st.integers(0, len(text)))].splitlines() or [""]
    return "\n".join(lines) + "\n"


def _as_in_file(df: pd.DataFrame, path: Path) -> None:
    """Every row of ``df`` is a line of the file, value for value (no truncation, no rounding, no invention)."""
    lines = {tuple(line.split(",")) for line in path.read_text(encoding="utf-8-sig").splitlines()[1:]}
    parsed = set()
    for fields in lines:
        if len(fields) != len(VEHICLE_COLUMNS):
            continue
        try:
            parsed.add(tuple(int(f) if c in ("track_id", "frame_id", "timestamp_ms") else
                             f if c == "agent_type" else float(f) for c, f in zip(VEHICLE_COLUMNS, fields)))
        except ValueError:
            continue
    for row in df.itertuples(index=False):
        assert tuple(row) in parsed, row


def _check_tracks(df: pd.DataFrame) -> None:
    """The invariants read_tracks promises."""
    assert list(df.columns) == list(VEHICLE_COLUMNS) and len(df)
    floats = df[["x", "y", "vx", "vy", "psi_rad", "length", "width"]].to_numpy()
    assert np.isfinite(floats).all()
    assert not df.duplicated(["track_id", "frame_id"]).any()
    offset = df["timestamp_ms"] - 100 * df["frame_id"]
    assert offset.nunique() == 1
    for _, g in df.groupby("track_id", sort=False):
        assert (np.diff(g["frame_id"].to_numpy()) > 0).all()


@needs_sample
@FUZZ
@given(text=mutated_text(SAMPLE_TRACKS.read_text() if SAMPLE_TRACKS.is_file() else ""))
def test_fuzz_track_csv_readers(tmp_path_factory, text):
    path = tmp_path_factory.mktemp("csv") / "vehicle_tracks_000.csv"
    path.write_text(text)
    try:
        df = read_tracks(path)
    except ValueError as exc:
        assert str(path) in str(exc)
    else:
        _check_tracks(df)
        _as_in_file(df, path)
    lenient, n_dropped = read_tracks_lenient(path)
    assert isinstance(n_dropped, int) and n_dropped >= 0
    if lenient is not None:
        _check_tracks(lenient)
        _as_in_file(lenient, path)


@FUZZ
@given(data=st.binary(max_size=300))
def test_fuzz_track_csv_random_bytes(tmp_path_factory, data):
    path = tmp_path_factory.mktemp("csv") / "vehicle_tracks_000.csv"
    path.write_bytes(data)
    with pytest.raises(ValueError):
        read_tracks(path)  # random bytes are never a valid track file with a header and rows
    df, n_dropped = read_tracks_lenient(path)
    assert df is None and n_dropped >= 0


# ---------------------------------------------------------------------------------------------- the map loader

OSM_FIELD = st.one_of(ODD_FIELDS, st.floats(-1e-3, 1e-3).map(repr), st.integers(-3, 30).map(str))


@st.composite
def mutated_osm(draw):
    """The sample map with a few attribute values replaced, lines deleted, or the text cut."""
    import re

    text = SAMPLE_MAP.read_text()
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["attr", "attr", "delete", "cut"]))
        if kind == "attr":
            attrs = list(re.finditer(r'(lat|lon|id|ref|v)="([^"]*)"', text))
            if not attrs:
                continue
            m = draw(st.sampled_from(attrs))
            value = draw(OSM_FIELD).replace('"', "&quot;").replace("<", "&lt;").replace("&", "&amp;")
            text = text[:m.start(2)] + value + text[m.end(2):]
        elif kind == "delete":
            lines = text.splitlines()
            if not lines:  # an earlier cut left nothing to delete
                continue
            del lines[draw(st.integers(0, len(lines) - 1))]
            text = "\n".join(lines)
        else:
            text = text[:draw(st.integers(0, len(text)))]
    return text


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(text=mutated_osm())
@needs_sample
def test_fuzz_map_loader(tmp_path_factory, text):
    pytest.importorskip("lanelet2")
    import xml.etree.ElementTree as ET

    from pirl_sim.io.lanelet2_map import load_map

    path = tmp_path_factory.mktemp("osm") / "map.osm"
    path.write_text(text)
    try:
        lmap = load_map(path)
    except ValueError as exc:
        assert str(path) in str(exc)
        return
    # loaded: then every node of the file had real coordinates (none was read as 0 silently) ...
    for node in ET.parse(path).getroot().iter("node"):
        assert math.isfinite(float(node.get("lat"))) and math.isfinite(float(node.get("lon")))
    # ... and every centerline is finite
    assert all(np.isfinite(line).all() for line in lmap.centerlines.values())


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_fuzz_map_loader_random_bytes(tmp_path_factory, data):
    pytest.importorskip("lanelet2")
    from pirl_sim.io.lanelet2_map import load_map

    path = tmp_path_factory.mktemp("osm") / "map.osm"
    path.write_bytes(data)
    with pytest.raises(ValueError, match="map.osm"):
        load_map(path)


# ---------------------------------------------------------------------------------------------- TOML values

TOML_SCALAR = st.one_of(st.booleans(), st.integers(-2**40, 2**40), st.floats(allow_nan=True, allow_infinity=True),
                        st.text(max_size=8), st.sampled_from(["full", "weird", "poisson", "regular", "tirl",
                                                              "pirl-gmm", "paper", "online", "synthetic"]))
TOML_VALUE = st.recursive(TOML_SCALAR, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                               st.dictionaries(st.text(max_size=6), inner,
                                                                               max_size=3)), max_leaves=6)


def _mutated_mapping(draw, base, keys: list[str]):
    """``base`` (a dict, changed in place) with some values replaced, some keys deleted, an unknown key added."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        key = draw(st.sampled_from(keys))
        if kind == "replace":
            base[key] = draw(TOML_VALUE)
        elif kind == "delete":
            base.pop(key, None)
        else:
            base[draw(st.text(min_size=1, max_size=6))] = draw(TOML_VALUE)
    return base


SWEEP_BASE = """
seeds = [0]
[[experiments]]
scenario = "synthetic"
params = { n_trajectories = 40, n_train = 30 }
protocols = [{ kind = "paper" }, { kind = "online", history_steps = 5 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2, covariance_type = "diag" } }]
"""


@st.composite
def sweep_dicts(draw):
    data = tomllib.loads(SWEEP_BASE)
    where = draw(st.sampled_from(["top", "experiment", "params", "protocol", "learner"]))
    exp = data["experiments"][0]
    if where == "top":
        _mutated_mapping(draw, data, ["seeds", "experiments", "name", "description"])
    elif where == "experiment":
        _mutated_mapping(draw, exp, ["scenario", "params", "protocols", "learners", "seeds", "label", "grid"])
    elif where == "params":
        _mutated_mapping(draw, exp["params"], ["n_trajectories", "n_train", "seed"])
    elif where == "protocol":
        _mutated_mapping(draw, exp["protocols"][1], ["kind", "history_steps", "horizon", "stride"])
    else:
        _mutated_mapping(draw, exp["learners"][1]["params"], ["n_components", "covariance_type", "log_bounds",
                                                              "random_state", "n_init"])
    return data


@FUZZ
@given(data=sweep_dicts())
def test_fuzz_sweep_config(data):
    from pirl_sim.engine.config import parse_config

    try:
        cfg = parse_config(data)
    except (ValueError, TypeError) as exc:
        assert str(exc)
        return
    for cell in cfg.cells:  # whatever was accepted hashes to a key (no NaN, nothing unserialisable)
        assert len(cell.key("v")) == 32
        assert 0 <= cell.seed < 2**31


@FUZZ
@given(data=st.binary(max_size=200))
def test_fuzz_sweep_toml_bytes(tmp_path_factory, data):
    from pirl_sim.engine.config import load_config

    path = tmp_path_factory.mktemp("toml") / "sweep.toml"
    path.write_bytes(data)
    with pytest.raises(ValueError):  # random bytes never make a sweep with experiments
        load_config(path)


POPULATION_KEYS = ["n_vehicles", "depart_interval", "depart_rate", "arrivals", "background_share", "control_noise",
                   "styles"]


@st.composite
def population_dicts(draw):
    from pirl_sim.scenarios.population_config import DEFAULT_POPULATION_TOML

    data = tomllib.loads(DEFAULT_POPULATION_TOML)
    if draw(st.booleans()):
        _mutated_mapping(draw, data, POPULATION_KEYS)
    else:
        style = data["styles"][draw(st.integers(0, 2))]
        target = draw(st.sampled_from(["style", "mean", "std"]))
        if target == "style":
            _mutated_mapping(draw, style, ["name", "weight", "mean", "std", "cov", "preset"])
        else:
            _mutated_mapping(draw, style[target], ["speed_dev", "acc_sq", "jerk_sq"])
    return data


@FUZZ
@given(data=population_dicts())
def test_fuzz_population_config(data):
    from pirl_sim.scenarios.population_config import population_from_dict

    try:
        pop = population_from_dict(data, source="fuzz.toml")
    except (ValueError, TypeError) as exc:
        assert "fuzz.toml" in str(exc)
        return
    # accepted: the values are the given ones, unchanged
    for key in ("n_vehicles", "background_share", "control_noise"):
        if key in data:
            assert getattr(pop, key) == data[key] and not isinstance(data[key], bool)
    if "depart_interval" in data:
        assert pop.depart_interval == data["depart_interval"]
    assert 1 <= pop.n_vehicles <= 100_000 and math.isfinite(pop.depart_interval) and pop.depart_interval > 0
    weights, styles = pop.sample_weights(5, np.random.default_rng(0))
    assert np.isfinite(weights).all() and (weights > 0).all()


@FUZZ
@given(data=st.binary(max_size=200))
def test_fuzz_population_toml_bytes(tmp_path_factory, data):
    from pirl_sim.scenarios.population_config import load_population

    path = tmp_path_factory.mktemp("toml") / "population.toml"
    path.write_bytes(data)
    try:
        load_population(path)  # an empty or comment-only file is the default population: allowed
    except ValueError as exc:
        assert str(path) in str(exc)


# ---------------------------------------------------------------------------------------------- env actions

ACTIONS = st.one_of(
    st.none(), st.booleans(), st.text(max_size=3), st.floats(allow_nan=True, allow_infinity=True),
    st.integers(-10**30, 10**30), st.lists(st.floats(allow_nan=True, allow_infinity=True), max_size=3),
    st.lists(st.floats(-5, 5), min_size=1, max_size=1).map(lambda v: np.array(v, dtype=np.float32)),
    st.lists(st.lists(st.floats(-2, 2), max_size=2), max_size=2),
)


@settings(max_examples=200, deadline=None)
@given(action=ACTIONS)
def test_fuzz_env_action_check(action):
    from pirl_sim.envs.common import acceleration, check_action

    try:
        x = check_action(action)
    except (TypeError, ValueError) as exc:
        assert "action must be" in str(exc)
        return
    value = float(np.asarray(action, dtype=float).reshape(-1)[0])
    assert np.isfinite(value) and x == min(max(value, -1.0), 1.0)
    assert -4.0 <= acceleration(action, (-4.0, 3.0)) <= 3.0


ENV_VALUES = st.one_of(TOML_SCALAR, st.none(), st.lists(TOML_SCALAR, max_size=3),
                       st.dictionaries(st.sampled_from(["type", "features", "vehicles_count", "acceleration_range",
                                                        "order", "clip"]), TOML_SCALAR, max_size=3))


@settings(max_examples=80, deadline=None)
@given(key=st.sampled_from(["policy_frequency", "duration", "ego_speed", "reward", "reward_theta", "action",
                            "observation", "progress_reward", "record_tracks", "population"]),
       value=ENV_VALUES)
def test_fuzz_env_common_config(key, value):
    from pirl_sim.envs.common import check_common, check_kinematics, common_defaults

    c = common_defaults()
    c[key] = value
    try:
        check_common(c)
        if key == "observation" and isinstance(value, dict):
            check_kinematics(value, ("presence", "x", "y"), "observation")
    except (TypeError, ValueError) as exc:
        assert str(exc)
