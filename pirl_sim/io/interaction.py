"""Read and write track files in the INTERACTION dataset's CSV format.

Vehicle files (``vehicle_tracks_NNN.csv``: ``track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,
width``) and pedestrian/bicycle files (``pedestrian_tracks_NNN.csv``: the first eight columns). Units: ms, m
(local map frame), m/s, rad; frames are 100 ms apart. Vehicle sizes must be positive and at most `MAX_LENGTH_M`
long and `MAX_WIDTH_M` wide. Errors are ``ValueError`` naming the file, the 1-based line (the header is line 1)
and the column. The format is described in the documentation's "File formats" page.
"""

from __future__ import annotations

import contextlib
import csv
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pandas as pd

from .atomic import atomic_write_text

__all__ = [
    "VEHICLE_COLUMNS",
    "PEDESTRIAN_COLUMNS",
    "FRAME_DT_MS",
    "MAX_LENGTH_M",
    "MAX_WIDTH_M",
    "read_tracks",
    "read_tracks_lenient",
    "write_tracks",
    "split_tracks",
    "iter_track_arrays",
    "find_track_files",
]

VEHICLE_COLUMNS: tuple[str, ...] = (
    "track_id", "frame_id", "timestamp_ms", "agent_type",
    "x", "y", "vx", "vy", "psi_rad", "length", "width",
)
PEDESTRIAN_COLUMNS: tuple[str, ...] = VEHICLE_COLUMNS[:8]
FRAME_DT_MS = 100  #: time between consecutive frames, ms
#: the largest vehicle sizes read [m]: beyond the longest road trains (about 53.5 m) and the widest oversize
#: loads; a size <= 0 or above these is an error in the file
MAX_LENGTH_M = 60.0
MAX_WIDTH_M = 10.0
_SIZE_LIMITS = {"length": MAX_LENGTH_M, "width": MAX_WIDTH_M}

_KINDS = {"vehicle": VEHICLE_COLUMNS, "pedestrian": PEDESTRIAN_COLUMNS}
_INT_COLUMNS = ("track_id", "frame_id", "timestamp_ms")
_STR_COLUMNS = ("agent_type",)

Where = Callable[[int], str]  # row position -> "line N" style location


# ----------------------------------------------------------------------------------------------
# public API
# ----------------------------------------------------------------------------------------------

def read_tracks(path, *, kind: str = "auto") -> pd.DataFrame:
    """Read one INTERACTION track CSV file and validate it (file-formats page: columns, units, checks).

    Parameters
    ----------
    path : str or os.PathLike                  the ``vehicle_tracks_NNN.csv`` or ``pedestrian_tracks_NNN.csv`` file
    kind : {"auto", "vehicle", "pedestrian"}   expected format; ``"auto"`` takes it from the header

    Returns
    -------
    tracks : pandas.DataFrame                  one row per line, in file order, the header's columns;
                                               FileNotFoundError, or ValueError naming the file, line and column
    """
    _check_kind(kind)
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"track file not found: {path}")
    with path.open(newline="", encoding="utf-8-sig") as fh:
        reader = csv.reader(fh)
        try:
            header = next(reader, None)
            if header is None:
                raise ValueError(f"{path}: file is empty (no header line)")
            columns = _resolve_columns(header, kind, f"{path}: line 1 (header)")
            rows, lines = [], []
            for row in reader:
                if not row:
                    continue
                if len(row) != len(columns):
                    raise ValueError(f"{path}: line {reader.line_num}: " + _field_count_problem(row, columns))
                rows.append(row)
                lines.append(reader.line_num)
        except csv.Error as exc:
            raise ValueError(f"{path}: line {reader.line_num}: malformed CSV: {exc}") from None
        except UnicodeDecodeError:
            raise ValueError(_not_utf8(path)) from None
    if not rows:
        raise ValueError(f"{path}: has no rows (header only)")
    raw = dict(zip(columns, (np.array(col) for col in zip(*rows))))
    return _validated_frame(raw, columns, str(path), lambda i: f"line {lines[i]}")


def _not_utf8(path: Path) -> str:
    """The message for a track file that is not UTF-8 text: the file, the line and the byte."""
    raw = path.read_bytes()
    try:
        raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        line = raw.count(b"\n", 0, exc.start) + 1
        return (f"{path}: line {line}: not UTF-8 text (byte {raw[exc.start:exc.start + 1]!r} at offset {exc.start}: "
                f"{exc.reason}); track files are UTF-8 CSV")
    return f"{path}: not UTF-8 text; track files are UTF-8 CSV"  # pragma: no cover - decoded above


def read_tracks_lenient(path) -> tuple[pd.DataFrame | None, int]:
    """Read the valid tracks of a vehicle track file, dropping every track with a bad row.

    The forgiving counterpart of `read_tracks`: a track is dropped, whole, when any of its rows fails a check (the
    file-formats page, INTERACTION tracks, lists them).

    Parameters
    ----------
    path : str or os.PathLike              a ``vehicle_tracks_NNN.csv`` file

    Returns
    -------
    frame : pandas.DataFrame or None       the kept tracks' rows in file order, as `read_tracks` returns them; None
                                           when the file is unreadable or no track is left
    n_dropped : int                        tracks dropped, plus one per row whose ``track_id`` is not an integer
    """
    path = Path(path)
    try:
        with path.open(newline="", encoding="utf-8-sig") as fh:
            lines = list(csv.reader(fh))
    except (OSError, UnicodeDecodeError, csv.Error):
        return None, 0
    if not lines or [h.strip() for h in lines[0]] != list(VEHICLE_COLUMNS):
        return None, 0
    n = len(VEHICLE_COLUMNS)
    unattributed = 0
    bad: set[int] = set()
    rows: list[list] = []
    for row in lines[1:]:
        if not row:
            continue
        try:
            track_id = int(row[0])
        except ValueError:
            unattributed += 1
            continue
        parsed = _lenient_row(row, n)
        if parsed is None:
            bad.add(track_id)
        else:
            rows.append(parsed)
    df = pd.DataFrame(rows, columns=list(VEHICLE_COLUMNS))
    if len(df):
        df = df.astype({c: np.int64 for c in _INT_COLUMNS})
        bad |= set(df.loc[df.duplicated(["track_id", "frame_id"], keep=False), "track_id"].tolist())
        previous = df.groupby("track_id", sort=False)["frame_id"].shift().to_numpy(dtype=np.float64)
        bad |= set(df.loc[df["frame_id"].to_numpy() <= previous, "track_id"].tolist())
        offset = df["timestamp_ms"] - FRAME_DT_MS * df["frame_id"]
        bad |= set(df.loc[offset != offset.mode().min(), "track_id"].tolist())
        df = df[~df["track_id"].isin(bad)].reset_index(drop=True)
    if df.empty:
        return None, len(bad) + unattributed
    return df, len(bad) + unattributed


def _lenient_row(row: list[str], n: int) -> list | None:
    """A row's values in their types, or None when a field is missing, extra or not what its column holds."""
    if len(row) != n:
        return None
    out: list = []
    for name, text in zip(VEHICLE_COLUMNS, row):
        if name in _INT_COLUMNS:
            try:
                value = int(text)
            except ValueError:
                return None
            if not -2**63 <= value < 2**63:  # beyond int64
                return None
            out.append(value)
        elif name in _STR_COLUMNS:
            if not text.strip():
                return None
            out.append(text)
        else:
            try:
                value = float(text)  # type: ignore[assignment]
            except ValueError:
                return None
            if not np.isfinite(value) or (name in _SIZE_LIMITS and not 0.0 < value <= _SIZE_LIMITS[name]):
                return None
            out.append(value)
    return out


def write_tracks(df: pd.DataFrame, path, *, kind: str = "auto") -> Path:
    """Validate ``df`` and write it atomically as an INTERACTION track CSV file (exact round trip; file-formats page).

    Parameters
    ----------
    df : pandas.DataFrame                      columns of `VEHICLE_COLUMNS` or `PEDESTRIAN_COLUMNS` (any order, no
                                               others; the index is not written), units as in `read_tracks`
    path : str or os.PathLike                  target file; missing parent directories are created
    kind : {"auto", "vehicle", "pedestrian"}   format to write; ``"auto"`` takes it from the columns

    Returns
    -------
    path : pathlib.Path                        the written file; ValueError (naming row, line and column) for an
                                               invalid ``kind`` or ``df``, and then nothing is written
    """
    _check_kind(kind)
    path = Path(path)
    if not isinstance(df, pd.DataFrame):
        raise TypeError(f"cannot write {path}: expected a pandas DataFrame, got {type(df).__name__}")
    columns = _resolve_columns(
        [str(c) for c in df.columns], kind, f"cannot write {path}: DataFrame columns", ordered=False
    )
    if len(df) == 0:
        raise ValueError(f"cannot write {path}: the DataFrame has no rows")
    raw = {name: df[name].to_numpy() for name in columns}
    clean = _validated_frame(raw, columns, f"cannot write {path}", lambda i: f"row {i} (line {i + 2} of the file)")
    atomic_write_text(path, clean.to_csv(index=False, lineterminator="\n"))
    return path


def split_tracks(df: pd.DataFrame) -> dict[int, pd.DataFrame]:
    """Split a track table into one table per track.

    Parameters
    ----------
    df : pandas.DataFrame
        Tracks as returned by :func:`read_tracks`.

    Returns
    -------
    dict of int (or str) to pandas.DataFrame
        ``{track_id: rows of that track sorted by frame_id}``, keys ascending, each with a fresh
        0-based index; keys are int, or str for a pedestrian file's named tracks (``P1``).
    """
    _require_columns(df, ("track_id", "frame_id"))
    return {
        (track_id if isinstance(track_id, str) else int(track_id)):  # type: ignore[misc]
            rows.sort_values("frame_id", kind="stable").reset_index(drop=True)
        for track_id, rows in df.groupby("track_id", sort=True)
    }


def iter_track_arrays(df: pd.DataFrame) -> Iterator[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Iterate over the tracks of a table as numpy arrays, by ascending ``track_id``, samples in ``frame_id`` order.

    Parameters
    ----------
    df : pandas.DataFrame          tracks as returned by `read_tracks`

    Yields
    ------
    track_id : int (str for a pedestrian file's named tracks)
    t_s : numpy.ndarray (n,)       time stamps [s] (``timestamp_ms / 1000``), increasing
    xy, v_xy : numpy.ndarray (n, 2)   positions (x, y) [m] and velocities (vx, vy) [m/s]
    """
    _require_columns(df, ("track_id", "frame_id", "timestamp_ms", "x", "y", "vx", "vy"))
    tracks = split_tracks(df)

    def generate():
        for track_id, rows in tracks.items():
            t_s = rows["timestamp_ms"].to_numpy(dtype=np.float64) / 1000.0
            xy = rows[["x", "y"]].to_numpy(dtype=np.float64)
            v_xy = rows[["vx", "vy"]].to_numpy(dtype=np.float64)
            yield track_id, t_s, xy, v_xy

    return generate()


def find_track_files(directory) -> list[Path]:
    """List the vehicle track files of a recording directory.

    Parameters
    ----------
    directory : str or os.PathLike   a ``recorded_trackfiles/<scenario>`` directory

    Returns
    -------
    paths : list of pathlib.Path     its ``vehicle_tracks_*.csv`` files (not recursive), sorted by name;
                                     FileNotFoundError without the directory, ValueError without such a file
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"track directory not found: {directory}")
    files = sorted(p for p in directory.glob("vehicle_tracks_*.csv") if p.is_file())
    if not files:
        raise ValueError(f"no vehicle_tracks_*.csv files in {directory}")
    return files


# ----------------------------------------------------------------------------------------------
# validation
# ----------------------------------------------------------------------------------------------

def _check_kind(kind) -> None:
    if kind != "auto" and kind not in _KINDS:
        raise ValueError(f"invalid kind {kind!r}; allowed: 'auto', 'vehicle', 'pedestrian'")


def _resolve_columns(header, kind: str, where: str, *, ordered: bool = True) -> tuple[str, ...]:
    """Return the expected columns for ``header``, or raise naming what is missing or unknown."""
    header = [h.strip() for h in header]
    if kind == "auto":
        # the format whose column set is nearest to the header
        kind = min(_KINDS, key=lambda k: (len(set(header) ^ set(_KINDS[k])), k != "vehicle"))
    expected = _KINDS[kind]
    matches = tuple(header) == expected if ordered else sorted(header) == sorted(expected)
    if matches:
        return expected
    problems = []
    missing = [c for c in expected if c not in header]
    unknown = [c for c in header if c not in expected]
    repeated = sorted({c for c in header if header.count(c) > 1})
    if missing:
        problems.append("missing column(s) " + ", ".join(map(repr, missing)))
    if unknown:
        problems.append("unknown column(s) " + ", ".join(map(repr, unknown)))
    if repeated:
        problems.append("repeated column(s) " + ", ".join(map(repr, repeated)))
    if not problems:
        problems.append("columns out of order")
    raise ValueError(
        f"{where}: {'; '.join(problems)}. Expected the {kind} columns {','.join(expected)}, "
        f"found {','.join(header)}"
    )


def _field_count_problem(row: list[str], columns: tuple[str, ...]) -> str:
    n, m = len(row), len(columns)
    if n < m:
        return (f"{n} of {m} fields, no value for column '{columns[n]}' and after "
                f"(truncated line? expected {','.join(columns)})")
    return f"{n} fields, {n - m} more than the {m} columns after column '{columns[-1]}'"


def _validated_frame(
    raw: dict[str, np.ndarray], columns: tuple[str, ...], source: str, loc: Where
) -> pd.DataFrame:
    """Convert the raw columns to their dtypes and check the track structure."""

    def where(i: int) -> str:
        return f"{source}: {loc(i)}"

    data = {}
    for name in columns:
        if name == "track_id" and columns == PEDESTRIAN_COLUMNS:
            data[name] = _pedestrian_ids(raw[name], name, where)
        elif name in _INT_COLUMNS:
            data[name] = _int_column(raw[name], name, where)
        elif name in _STR_COLUMNS:
            data[name] = _str_column(raw[name], name, where)
        else:
            data[name] = _float_column(raw[name], name, where)
            if name in _SIZE_LIMITS:
                _check_sizes(data[name], name, where)
    df = pd.DataFrame(data, columns=list(columns))
    df["agent_type"] = df["agent_type"].astype(str)
    _check_structure(df, where, loc)
    return df


def _int_column(values: np.ndarray, name: str, where: Where) -> np.ndarray:
    if values.dtype.kind in "iu":
        return values.astype(np.int64)
    if values.dtype.kind == "U":
        with contextlib.suppress(ValueError, OverflowError):
            return values.astype(np.int64)
    out = np.empty(len(values), dtype=np.int64)
    for i, v in enumerate(values):
        try:
            out[i] = _parse_int(v)
        except (TypeError, ValueError, OverflowError):
            raise ValueError(f"{where(i)}, column '{name}': expected an integer, found {_show(v)}") from None
    return out


def _pedestrian_ids(values: np.ndarray, name: str, where: Where):
    """A pedestrian file's track ids: int64 when every id is a whole number (as a vehicle file's), else the ids as
    non-empty strings (the INTERACTION dataset names pedestrian tracks ``P1``, ``P2``, ...)."""
    try:
        return _int_column(values, name, where)
    except ValueError:
        pass
    out = np.empty(len(values), dtype=object)
    for i, v in enumerate(values):
        if isinstance(v, str) and v.strip():
            out[i] = v.strip()
        else:
            try:
                out[i] = str(_parse_int(v))
            except (TypeError, ValueError, OverflowError):
                raise ValueError(f"{where(i)}, column '{name}': expected a track name or an integer, found "
                                 f"{_show(v)}") from None
    return out


def _check_sizes(values: np.ndarray, name: str, where: Where) -> None:
    high = _SIZE_LIMITS[name]
    bad = np.flatnonzero(~((values > 0.0) & (values <= high)))
    if bad.size:
        i = int(bad[0])
        raise ValueError(f"{where(i)}, column '{name}': {values[i]:g} m is not a vehicle {name} (must be > 0 and "
                         f"at most {high:g} m)")


def _parse_int(v) -> int:
    if isinstance(v, (bool, np.bool_)):
        raise TypeError
    if isinstance(v, (int, np.integer)):
        return int(v)
    if isinstance(v, (float, np.floating)) and float(v).is_integer():
        return int(v)
    if isinstance(v, str):
        return int(v)
    raise TypeError


def _float_column(values: np.ndarray, name: str, where: Where) -> np.ndarray:
    try:
        out = values.astype(np.float64)
    except (TypeError, ValueError):
        for i, v in enumerate(values):
            try:
                float(v)
            except (TypeError, ValueError):
                raise ValueError(f"{where(i)}, column '{name}': expected a number, found {_show(v)}") from None
        raise  # unreachable in practice: every element converted on its own
    bad = np.flatnonzero(~np.isfinite(out))
    if bad.size:
        i = bad[0]
        raise ValueError(f"{where(i)}, column '{name}': {out[i]} is not allowed (values must be finite)")
    return out


def _str_column(values: np.ndarray, name: str, where: Where) -> list[str]:
    out = []
    for i, v in enumerate(values):
        if not isinstance(v, str) or not v.strip():
            raise ValueError(f"{where(i)}, column '{name}': expected a non-empty string, found {_show(v)}")
        out.append(str(v))
    return out


def _show(v) -> str:
    if isinstance(v, str):
        return "an empty value" if not v.strip() else repr(str(v))
    return "a missing value (NaN)" if pd.isna(v) else repr(v)


def _check_structure(df: pd.DataFrame, where: Where, loc: Where) -> None:
    track = df["track_id"].to_numpy()
    frame = df["frame_id"].to_numpy()
    stamp = df["timestamp_ms"].to_numpy()

    duplicated = df.duplicated(["track_id", "frame_id"], keep="first").to_numpy()
    if duplicated.any():
        i = int(np.argmax(duplicated))
        first = int(np.flatnonzero((track == track[i]) & (frame == frame[i]))[0])
        raise ValueError(
            f"{where(i)}, column 'frame_id': duplicated (track_id, frame_id) = ({track[i]}, {frame[i]}), "
            f"first at {loc(first)}"
        )

    previous = df.groupby("track_id", sort=False)["frame_id"].shift().to_numpy(dtype=np.float64)
    decreasing = frame <= previous  # NaN (first row of a track) compares False
    if decreasing.any():
        i = int(np.argmax(decreasing))
        raise ValueError(
            f"{where(i)}, column 'frame_id': frame_id {frame[i]} of track {track[i]} follows frame_id "
            f"{int(previous[i])} of that track; frames must increase strictly within a track"
        )

    offset = stamp - FRAME_DT_MS * frame
    wrong = offset != offset[0]
    if wrong.any():
        i = int(np.argmax(wrong))
        raise ValueError(
            f"{where(i)}, column 'timestamp_ms': timestamp_ms {stamp[i]} does not fit frame_id {frame[i]}; "
            f"expected {FRAME_DT_MS * frame[i] + offset[0]} ({FRAME_DT_MS} ms per frame, offset "
            f"{offset[0]} ms as at {loc(0)})"
        )


def _require_columns(df: pd.DataFrame, names: tuple[str, ...]) -> None:
    missing = [c for c in names if c not in df.columns]
    if missing:
        raise ValueError(f"track table lacks column(s) {', '.join(map(repr, missing))}")
