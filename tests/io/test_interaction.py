"""INTERACTION track files (pirl_sim.io.interaction): reading and writing, every bad file a ValueError naming the
file and line, the lenient reader, and fuzzed files (hypothesis)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from pirl_sim.io import atomic, interaction
from pirl_sim.io.interaction import (
    MAX_LENGTH_M,
    MAX_WIDTH_M,
    PEDESTRIAN_COLUMNS,
    VEHICLE_COLUMNS,
    find_track_files,
    iter_track_arrays,
    read_tracks,
    read_tracks_lenient,
    split_tracks,
    write_tracks,
)

from shared_sample import SAMPLE_DIR, SAMPLE_TRACKS, needs_sample
from shared_sample import SAMPLE_TRACKS as SAMPLE

pytest.importorskip("hypothesis")

from hypothesis import given  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from toml_fuzz import FUZZ, read_or_error_naming_it  # noqa: E402


VEHICLE_HEADER = ",".join(VEHICLE_COLUMNS)
PEDESTRIAN_HEADER = ",".join(PEDESTRIAN_COLUMNS)


def random_tracks(seed: int, *, n_tracks: int = 4, n_frames: int = 30, pedestrian: bool = False) -> pd.DataFrame:
    rng = np.random.default_rng(seed)
    parts = []
    for track_id in range(1, n_tracks + 1):
        start = int(rng.integers(1, 50))
        frame = np.arange(start, start + n_frames)
        part = {
            "track_id": np.full(n_frames, track_id),
            "frame_id": frame,
            "timestamp_ms": 100 * frame,
            "agent_type": ["pedestrian/bicycle" if pedestrian else "car"] * n_frames,
            "x": rng.uniform(800.0, 1200.0, n_frames),
            "y": rng.uniform(900.0, 1100.0, n_frames),
            "vx": rng.normal(0.0, 5.0, n_frames),
            "vy": rng.normal(0.0, 5.0, n_frames),
        }
        if not pedestrian:
            part |= {
                "psi_rad": rng.uniform(-np.pi, np.pi, n_frames),
                "length": np.full(n_frames, rng.uniform(3.5, 5.5)),
                "width": np.full(n_frames, rng.uniform(1.6, 2.1)),
            }
        parts.append(pd.DataFrame(part))
    return pd.concat(parts, ignore_index=True)


def write_text(tmp_path: Path, text: str, name: str = "vehicle_tracks_000.csv") -> Path:
    path = tmp_path / name
    path.write_text(text)
    return path


def good_vehicle_lines() -> list[str]:
    return [
        VEHICLE_HEADER,
        "1,1,100,car,1.0,2.5,10,0,0,4,1.8",
        "1,2,200,car,2.0,2.5,10,0,0,4,1.8",
        "2,2,200,car,5.0,6.5,0,1,1.57,4.5,1.9",
        "2,3,300,car,5.0,6.6,0,1,1.57,4.5,1.9",
    ]


def assert_rejected(tmp_path: Path, lines: list[str], match: str) -> None:
    """``lines`` written as a vehicle track file fail to read with a ValueError matching ``match``."""
    with pytest.raises(ValueError, match=match):
        read_tracks(write_text(tmp_path, "\n".join(lines)))


def assert_edit_rejected(tmp_path: Path, line: int, old: str, new: str, match: str) -> None:
    """`good_vehicle_lines` with ``old`` replaced by ``new`` in line index ``line`` fail to read (`assert_rejected`)."""
    lines = good_vehicle_lines()
    lines[line] = lines[line].replace(old, new)
    assert_rejected(tmp_path, lines, match)


def assert_frames_close(a: pd.DataFrame, b: pd.DataFrame, atol: float = 1e-6) -> None:
    assert list(a.columns) == list(b.columns)
    assert len(a) == len(b)
    for name in a.columns:
        if name == "agent_type":
            assert list(a[name]) == list(b[name])
        elif name in ("track_id", "frame_id", "timestamp_ms"):
            np.testing.assert_array_equal(a[name].to_numpy(), b[name].to_numpy())
        else:
            np.testing.assert_allclose(a[name].to_numpy(), b[name].to_numpy(), rtol=0.0, atol=atol)


def assert_dtypes(df: pd.DataFrame) -> None:
    for name in ("track_id", "frame_id", "timestamp_ms"):
        assert df[name].dtype == np.int64, name
    assert pd.api.types.is_string_dtype(df["agent_type"])
    assert all(isinstance(v, str) for v in df["agent_type"])
    for name in df.columns[4:]:
        assert df[name].dtype == np.float64, name

@needs_sample
def test_read_shared_sample():
    df = read_tracks(SAMPLE)
    assert list(df.columns) == list(VEHICLE_COLUMNS)
    assert len(df) == 170
    assert sorted(df["track_id"].unique()) == [1, 2]
    assert_dtypes(df)
    assert (df["timestamp_ms"] == 100 * df["frame_id"]).all()
    assert read_tracks(SAMPLE, kind="vehicle").equals(df)


@needs_sample
def test_sample_round_trip(tmp_path):
    df = read_tracks(SAMPLE)
    out = write_tracks(df, tmp_path / "vehicle_tracks_000.csv")
    back = read_tracks(out)
    assert_frames_close(df, back)
    assert_dtypes(back)
    assert out.read_text().splitlines()[0] == VEHICLE_HEADER


@needs_sample
def test_find_track_files_on_sample():
    assert find_track_files(SAMPLE_DIR) == [SAMPLE]

@pytest.mark.parametrize("seed", [0, 1])
def test_round_trip_random_vehicle(tmp_path, seed):
    df = random_tracks(seed)
    path = write_tracks(df, tmp_path / "nested" / "dir" / "vehicle_tracks_001.csv")  # parents created
    back = read_tracks(path)
    assert_frames_close(df, back, atol=1e-6)
    assert_dtypes(back)
    # shortest-repr floats: the round trip is in fact exact, and stays so when repeated
    pd.testing.assert_frame_equal(back, read_tracks(write_tracks(back, tmp_path / "again.csv")))
    np.testing.assert_array_equal(back["x"].to_numpy(), df["x"].to_numpy())


def test_written_text_format(tmp_path):
    df = random_tracks(3, n_tracks=1, n_frames=2)
    lines = write_tracks(df, tmp_path / "t.csv").read_text().splitlines()
    assert lines[0] == VEHICLE_HEADER
    fields = lines[1].split(",")
    assert len(fields) == 11
    assert fields[:4] == ["1", str(df.frame_id[0]), str(df.timestamp_ms[0]), "car"]  # ints stay ints


def test_write_reorders_columns(tmp_path):
    df = random_tracks(4)
    shuffled = df[list(reversed(df.columns))]
    back = read_tracks(write_tracks(shuffled, tmp_path / "t.csv"))
    assert_frames_close(df, back)


def test_pedestrian_read_and_write(tmp_path):
    text = "\n".join([
        PEDESTRIAN_HEADER,
        "P1,1,100,pedestrian/bicycle,1.0,2.0,0.5,0.0",
    ])
    named = read_tracks(write_text(tmp_path, text, "pedestrian_tracks_000.csv"))  # the dataset's pedestrian ids
    assert named["track_id"].tolist() == ["P1"]

    text = "\n".join([
        PEDESTRIAN_HEADER,
        "1,1,100,pedestrian/bicycle,1.0,2.0,0.5,0.0",
        "1,2,200,pedestrian/bicycle,1.05,2.0,0.5,0.0",
        "3,2,200,pedestrian/bicycle,7.0,3.0,0.0,-1.2",
    ]) + "\n"
    path = write_text(tmp_path, text, "pedestrian_tracks_000.csv")
    df = read_tracks(path)
    assert list(df.columns) == list(PEDESTRIAN_COLUMNS)
    assert len(df) == 3
    assert_dtypes(df)
    assert read_tracks(path, kind="pedestrian").equals(df)

    out = write_tracks(df, tmp_path / "out" / "pedestrian_tracks_000.csv")
    assert out.read_text().splitlines()[0] == PEDESTRIAN_HEADER
    assert_frames_close(df, read_tracks(out))

    generated = random_tracks(5, pedestrian=True)
    assert_frames_close(generated, read_tracks(write_tracks(generated, tmp_path / "p.csv")))


def test_pedestrian_file_read_as_vehicle_is_rejected(tmp_path):
    path = write_text(tmp_path, PEDESTRIAN_HEADER + "\n1,1,100,pedestrian/bicycle,1,2,0,0\n")
    with pytest.raises(ValueError, match=r"line 1.*missing column\(s\) 'psi_rad', 'length', 'width'"):
        read_tracks(path, kind="vehicle")

def test_split_tracks_and_arrays():
    df = random_tracks(6, n_tracks=3, n_frames=5).sample(frac=1.0, random_state=0)  # shuffled rows
    tracks = split_tracks(df)
    assert list(tracks) == [1, 2, 3]
    for track_id, rows in tracks.items():
        assert (rows["track_id"] == track_id).all()
        assert rows["frame_id"].is_monotonic_increasing
        assert list(rows.index) == list(range(5))

    seen = []
    for track_id, t_s, xy, v_xy in iter_track_arrays(df):
        rows = tracks[track_id]
        seen.append(track_id)
        assert t_s.shape == (5,) and xy.shape == (5, 2) and v_xy.shape == (5, 2)
        np.testing.assert_allclose(np.diff(t_s), 0.1)
        np.testing.assert_allclose(t_s, rows["frame_id"].to_numpy() * 0.1)
        np.testing.assert_array_equal(xy, rows[["x", "y"]].to_numpy())
        np.testing.assert_array_equal(v_xy, rows[["vx", "vy"]].to_numpy())
    assert seen == [1, 2, 3]

    with pytest.raises(ValueError, match="'vx'"):
        iter_track_arrays(df.drop(columns="vx"))


def test_find_track_files(tmp_path):
    with pytest.raises(ValueError, match=str(tmp_path)):
        find_track_files(tmp_path)
    for name in ("vehicle_tracks_002.csv", "vehicle_tracks_000.csv", "pedestrian_tracks_000.csv", "notes.txt"):
        (tmp_path / name).write_text("x")
    assert find_track_files(tmp_path) == [tmp_path / "vehicle_tracks_000.csv", tmp_path / "vehicle_tracks_002.csv"]
    with pytest.raises(FileNotFoundError):
        find_track_files(tmp_path / "nope")

def test_missing_file(tmp_path):
    with pytest.raises(FileNotFoundError, match="nothere.csv"):
        read_tracks(tmp_path / "nothere.csv")


def test_bad_kind(tmp_path):
    path = write_text(tmp_path, "\n".join(good_vehicle_lines()))
    with pytest.raises(ValueError, match=r"'bicycle'.*'auto', 'vehicle', 'pedestrian'"):
        read_tracks(path, kind="bicycle")
    with pytest.raises(ValueError, match=r"'bicycle'"):
        write_tracks(read_tracks(path), tmp_path / "out.csv", kind="bicycle")


def test_truncated_last_line(tmp_path):
    text = "\n".join(good_vehicle_lines())
    path = write_text(tmp_path, text[: text.rindex(",4.5,")])  # cut mid-row, after psi_rad
    with pytest.raises(ValueError, match=r"vehicle_tracks_000\.csv: line 5: 9 of 11 fields.*column 'length'"):
        read_tracks(path)


def test_too_many_fields(tmp_path):
    lines = good_vehicle_lines()
    lines[2] += ",7"
    assert_rejected(tmp_path, lines, r"line 3: 12 fields")


def test_missing_column(tmp_path):
    lines = [",".join(line.split(",")[:4] + line.split(",")[5:]) for line in good_vehicle_lines()]  # drop x
    path = write_text(tmp_path, "\n".join(lines))
    with pytest.raises(ValueError, match=r"line 1 \(header\): missing column\(s\) 'x'.*Expected .*track_id,frame_id"):
        read_tracks(path)


def test_unknown_and_misordered_columns(tmp_path):
    lines = good_vehicle_lines()
    lines[0] = lines[0].replace("psi_rad", "heading")
    assert_rejected(tmp_path, lines, r"missing column\(s\) 'psi_rad'; unknown column\(s\) 'heading'")
    lines[0] = VEHICLE_HEADER.replace("x,y", "y,x")
    assert_rejected(tmp_path, lines, r"line 1 \(header\): columns out of order")


def test_header_only(tmp_path):
    with pytest.raises(ValueError, match="no rows"):
        read_tracks(write_text(tmp_path, VEHICLE_HEADER + "\n"))
    with pytest.raises(ValueError, match="empty"):
        read_tracks(write_text(tmp_path, ""))


@pytest.mark.parametrize("value", ["nan", "NaN", "inf", "-inf"])
def test_nan_or_inf_value(tmp_path, value):
    assert_edit_rejected(tmp_path, 3, ",6.5,", f",{value},", r"line 4, column 'y':.*finite")


def test_empty_value(tmp_path):
    assert_edit_rejected(tmp_path, 2, ",10,", ",,", r"line 3, column 'vx': expected a number, found an empty value")


def test_non_numeric_x(tmp_path):
    assert_edit_rejected(tmp_path, 4, ",5.0,", ",five,", r"line 5, column 'x': expected a number, found 'five'")


def test_duplicated_frame(tmp_path):
    lines = good_vehicle_lines()
    lines.append(lines[2])  # track 1, frame 2 again, at line 6
    assert_rejected(tmp_path, lines, r"line 6, column 'frame_id': duplicated .*\(1, 2\), first at line 3")


def test_non_monotonic_frames(tmp_path):
    lines = good_vehicle_lines()
    lines[3], lines[4] = lines[4], lines[3]  # track 2: frame 3 before frame 2
    assert_rejected(tmp_path, lines, r"line 5, column 'frame_id': frame_id 2 of track 2 follows frame_id 3")


def test_inconsistent_timestamp(tmp_path):
    assert_edit_rejected(tmp_path, 4, ",300,", ",350,",
                         r"line 5, column 'timestamp_ms': timestamp_ms 350 .*expected 300")


def test_constant_timestamp_offset_is_accepted(tmp_path):
    lines = good_vehicle_lines()
    for i, t in zip(range(1, 5), (150, 250, 250, 350)):
        fields = lines[i].split(",")
        fields[2] = str(t)
        lines[i] = ",".join(fields)
    assert len(read_tracks(write_text(tmp_path, "\n".join(lines)))) == 4


def test_blank_lines_and_crlf_keep_line_numbers(tmp_path):
    lines = good_vehicle_lines()
    lines.insert(2, "")
    lines[4] = lines[4].replace(",5.0,", ",x,")  # now at line 5
    path = tmp_path / "crlf.csv"
    path.write_bytes("\r\n".join(lines).encode())
    with pytest.raises(ValueError, match=r"line 5, column 'x'"):
        read_tracks(path)


def test_write_rejects_bad_frames(tmp_path):
    df = random_tracks(7, n_tracks=2, n_frames=3)
    target = tmp_path / "t.csv"

    bad = df.copy()
    bad.loc[4, "y"] = np.nan
    with pytest.raises(ValueError, match=r"row 4 \(line 6 of the file\), column 'y'"):
        write_tracks(bad, target)

    bad = df.astype({"x": object})
    bad.loc[1, "x"] = "abc"
    with pytest.raises(ValueError, match=r"row 1 .*column 'x': expected a number, found 'abc'"):
        write_tracks(bad, target)

    bad = df.astype({"track_id": float})
    bad.loc[2, "track_id"] = 1.5
    with pytest.raises(ValueError, match=r"row 2 .*column 'track_id': expected an integer"):
        write_tracks(bad, target)

    with pytest.raises(ValueError, match=r"missing column\(s\) 'width'"):
        write_tracks(df.drop(columns="width"), target)
    with pytest.raises(ValueError, match=r"unknown column\(s\) 'speed'"):
        write_tracks(df.assign(speed=1.0), target)
    with pytest.raises(ValueError, match=r"row 3 .*column 'frame_id': duplicated"):
        write_tracks(pd.concat([df.iloc[:3], df.iloc[[2]]], ignore_index=True), target)
    with pytest.raises(ValueError, match="no rows"):
        write_tracks(df.iloc[:0], target)
    assert not target.exists()

    # integral floats are accepted and written as ints
    ok = df.astype({"frame_id": float})
    assert "\n1,%d,%d,car," % (df.frame_id[0], df.timestamp_ms[0]) in write_tracks(ok, target).read_text()

class _HalfWriter:
    """A file wrapper whose write() writes half of the text, then fails like a full disk."""

    def __init__(self, fh):
        self._fh = fh

    def write(self, text):
        self._fh.write(text[: len(text) // 2])
        self._fh.flush()
        raise OSError(28, "No space left on device (simulated)")

    def __getattr__(self, name):
        return getattr(self._fh, name)

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self._fh.close()
        return False


def _fail_write(monkeypatch):
    real_fdopen = os.fdopen
    monkeypatch.setattr(atomic.os, "fdopen", lambda *a, **k: _HalfWriter(real_fdopen(*a, **k)))


def _fail_fsync(monkeypatch):
    def boom(fd):
        raise OSError(5, "I/O error (simulated)")
    monkeypatch.setattr(atomic.os, "fsync", boom)


def _fail_replace(monkeypatch):
    def boom(src, dst):
        raise OSError(5, "I/O error (simulated)")
    monkeypatch.setattr(atomic.os, "replace", boom)


@pytest.mark.parametrize("fail", [_fail_write, _fail_fsync, _fail_replace], ids=["write", "fsync", "replace"])
@pytest.mark.parametrize("existing", [False, True], ids=["new", "overwrite"])
def test_atomic_write_leaves_no_partial_file(tmp_path, monkeypatch, fail, existing):
    target = tmp_path / "vehicle_tracks_000.csv"
    old = "previous contents\n"
    if existing:
        target.write_text(old)
    df = random_tracks(8, n_tracks=3, n_frames=200)

    fail(monkeypatch)
    with pytest.raises(OSError, match="simulated"):
        write_tracks(df, target)
    monkeypatch.undo()

    assert sorted(p.name for p in tmp_path.iterdir()) == ([target.name] if existing else [])
    if existing:
        assert target.read_text() == old
    # and with the failure gone the write goes through
    assert_frames_close(df, read_tracks(write_tracks(df, target)))
    assert sorted(p.name for p in tmp_path.iterdir()) == [target.name]


def test_non_utf8_track_file_is_a_value_error_naming_the_file_and_line(tmp_path):
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_bytes((VEHICLE_HEADER + "\n1,1,100,car,1.0,2.0,0,0,0,4.5,1.8\n").encode()
                     + b"1,2,200,c\xe9r,1,2,0,0,0,4.5,1.8\n")
    with pytest.raises(ValueError, match=r"vehicle_tracks_000\.csv: line 3: not UTF-8 text \(byte b'\\xe9'"):
        read_tracks(path)


def test_pedestrian_files_with_named_tracks_are_read_with_their_names(tmp_path):
    path = tmp_path / "pedestrian_tracks_000.csv"
    path.write_text("\n".join([PEDESTRIAN_HEADER, "P1,1,100,pedestrian/bicycle,1.0,2.0,0.5,0.0",
                               "P1,2,200,pedestrian/bicycle,1.05,2.0,0.5,0.0",
                               "P2,2,200,pedestrian/bicycle,7.0,3.0,0.0,-1.2"]) + "\n")
    df = read_tracks(path)
    assert df["track_id"].tolist() == ["P1", "P1", "P2"]
    assert sorted(split_tracks(df)) == ["P1", "P2"] and len(split_tracks(df)["P1"]) == 2
    back = read_tracks(write_tracks(df, tmp_path / "out" / "pedestrian_tracks_000.csv"))
    assert back.equals(df)
    with pytest.raises(ValueError, match=r"line 5, column 'frame_id': duplicated \(track_id, frame_id\) = \(P1, 2\)"):
        path.write_text(path.read_text() + "P1,2,200,pedestrian/bicycle,1.0,2.0,0.5,0.0\n")
        read_tracks(path)


def test_vehicle_track_ids_stay_integers_and_names_are_refused(tmp_path):
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text(VEHICLE_HEADER + "\n7,1,100,car,1.0,2.0,0,0,0,4.5,1.8\n")
    assert read_tracks(path)["track_id"].dtype == np.int64 and list(split_tracks(read_tracks(path))) == [7]
    path.write_text(VEHICLE_HEADER + "\nV7,1,100,car,1.0,2.0,0,0,0,4.5,1.8\n")
    with pytest.raises(ValueError, match=r"line 2, column 'track_id': expected an integer, found 'V7'"):
        read_tracks(path)


@pytest.mark.parametrize("column,value", [("length", "-4"), ("length", "0"), ("length", "1e6"), ("width", "-1.8"),
                                          ("width", "25")])
def test_vehicle_sizes_must_be_positive_and_plausible(tmp_path, column, value):
    sizes = {"length": "4.5", "width": "1.8", column: value}
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text(VEHICLE_HEADER + "\n1,1,100,car,1.0,2.0,0,0,0,4.5,1.8\n"
                    + f"2,1,100,car,1.0,2.0,0,0,0,{sizes['length']},{sizes['width']}\n")
    high = MAX_LENGTH_M if column == "length" else MAX_WIDTH_M
    with pytest.raises(ValueError, match=rf"vehicle_tracks_000\.csv: line 3, column '{column}': .* m is not a vehicle "
                                         rf"{column} \(must be > 0 and at most {high:g} m\)"):
        read_tracks(path)
    df, n_dropped = read_tracks_lenient(path)
    assert df["track_id"].tolist() == [1] and n_dropped == 1


def _sample_lines() -> list[str]:
    return SAMPLE_TRACKS.read_text().splitlines()


@needs_sample
def test_lenient_reader_keeps_a_clean_file_whole():
    df, n_dropped = interaction.read_tracks_lenient(SAMPLE_TRACKS)
    assert n_dropped == 0 and df.equals(read_tracks(SAMPLE_TRACKS))


@needs_sample
def test_lenient_reader_does_not_truncate_a_fractional_track_id(tmp_path):
    lines = _sample_lines()
    fields = lines[5].split(",")
    fields[0] = "1.5"
    lines[5] = ",".join(fields)
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text("\n".join(lines) + "\n")
    df, n_dropped = interaction.read_tracks_lenient(path)
    assert n_dropped == 1  # the row of no track is counted, not read as track 1
    assert len(df) == 169 and set(df["track_id"]) == {1, 2}
    assert 5 not in set(df.loc[df["track_id"] == 1, "frame_id"])  # line 6 held frame 5 of track 1


@needs_sample
def test_lenient_reader_drops_a_track_whose_timestamps_run_backwards(tmp_path):
    lines = _sample_lines()
    rows = [i for i in range(1, len(lines)) if lines[i].split(",")[0] == "2"]
    stamps = [lines[i].split(",")[2] for i in rows]
    for i, stamp in zip(rows, reversed(stamps)):
        fields = lines[i].split(",")
        fields[2] = stamp
        lines[i] = ",".join(fields)
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_text("\n".join(lines) + "\n")
    df, n_dropped = interaction.read_tracks_lenient(path)
    assert n_dropped == 1 and set(df["track_id"]) == {1}
    with pytest.raises(ValueError, match="timestamp_ms"):
        read_tracks(path)  # the strict reader names the row


@pytest.mark.parametrize("content", [b"", b"\xff\xfe\x00binary", b"a,b,c\n1,2,3\n"])
def test_lenient_reader_on_unreadable_files_returns_none(tmp_path, content):
    path = tmp_path / "vehicle_tracks_000.csv"
    path.write_bytes(content)
    assert interaction.read_tracks_lenient(path) == (None, 0)


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
    loaded, df = read_or_error_naming_it(read_tracks, path)
    if loaded:
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
