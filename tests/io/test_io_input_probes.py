"""Track files and Lanelet2 maps that look valid to one reader and not to another: refused, naming the file."""

from __future__ import annotations

import numpy as np
import pytest

from pirl_sim.io.interaction import MAX_LENGTH_M, MAX_WIDTH_M, read_tracks, read_tracks_lenient, split_tracks, \
    write_tracks
from pirl_sim.io.tables import read_csv_table

VEHICLE_HEADER = "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy,psi_rad,length,width"
PEDESTRIAN_HEADER = "track_id,frame_id,timestamp_ms,agent_type,x,y,vx,vy"


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


def test_a_recording_table_names_the_file_line_and_column_of_a_bad_value(tmp_path):
    path = tmp_path / "driver_steps.csv"
    path.write_text("track_id,frame_id,commanded,overridden,collided\n1,1,True,False,False\n1,2,,False,False\n")
    dtype = {"track_id": np.int64, "frame_id": np.int64, "commanded": bool, "overridden": bool, "collided": bool}
    with pytest.raises(ValueError, match=r"driver_steps\.csv: line 3, column 'commanded': expected True or False, "
                                         r"found an empty value"):
        read_csv_table(path, dtype)
    path.write_text("track_id,frame_id,commanded,overridden,collided\nx,1,True,False,False\n")
    with pytest.raises(ValueError, match=r"driver_steps\.csv: line 2, column 'track_id': expected an integer, "
                                         r"found 'x'"):
        read_csv_table(path, dtype)
    path.write_text("track_id,frame_id,commanded,overridden,collided\n1,1,True,False,False\n")
    assert read_csv_table(path, dtype)["commanded"].tolist() == [True]


# ---------------------------------------------------------------------------------------------- Lanelet2 maps
def _osm(lat="0.00002", left=(1, 2), right=(3, 4), right_way=11, doctype=""):
    nodes = {1: ("0.0", "0.0"), 2: ("0.0", "0.0002"), 3: (lat, "0.0"), 4: ("0.00002", "0.0002")}
    out = ['<?xml version="1.0"?>', doctype, '<osm version="0.6">']
    out += [f'<node id="{i}" lat="{la}" lon="{lo}"/>' for i, (la, lo) in nodes.items()]
    for way, refs in ((10, left), (11, right)):
        out.append(f'<way id="{way}">' + "".join(f'<nd ref="{i}"/>' for i in refs)
                   + '<tag k="type" v="line_thin"/><tag k="subtype" v="solid"/></way>')
    out.append(f'<relation id="20"><member type="way" ref="10" role="left"/><member type="way" ref="{right_way}" '
               'role="right"/><tag k="type" v="lanelet"/><tag k="subtype" v="road"/><tag k="location" v="urban"/>'
               '<tag k="one_way" v="yes"/></relation>')
    return "\n".join(out + ["</osm>"])


@pytest.fixture
def load_map():
    pytest.importorskip("lanelet2", reason="lanelet2 (the 'maps' extra) is not installed")
    from pirl_sim.io.lanelet2_map import load_map

    return load_map


def test_a_plain_lanelet_loads(tmp_path, load_map):
    (tmp_path / "ok.osm").write_text(_osm())
    assert load_map(tmp_path / "ok.osm").lanelet_ids == (20,)


@pytest.mark.parametrize("lat", ["0.00_002", "٠.٠٠٠٠٢", "０.００００２", "0.0\u20030"])
def test_coordinates_lanelet2_reads_differently_are_refused(tmp_path, load_map, lat):
    (tmp_path / "m.osm").write_text(_osm(lat=lat), encoding="utf-8")
    with pytest.raises(ValueError, match=r"m\.osm: node 3 has lat=.*ASCII digits.*no digit separators"):
        load_map(tmp_path / "m.osm")


def test_a_dtd_entity_is_refused(tmp_path, load_map):
    (tmp_path / "m.osm").write_text(_osm(lat="&x;", doctype='<!DOCTYPE osm [<!ENTITY x "0.00002">]>'))
    with pytest.raises(ValueError, match=r"m\.osm: the file has a DTD.*lanelet2 does not expand its entities"):
        load_map(tmp_path / "m.osm")


@pytest.mark.parametrize("kw,message", [
    ({"left": (1,)}, r"lanelet 20 has a left border \(line 10\) of 1 node\(s\); a border needs at least two"),
    ({"right_way": 10}, r"lanelet 20 has its left border \(line 10\) and its right border \(line 10\) on the same"),
    ({"right": (1, 2)}, r"lanelet 20 has its left border \(line 10\) and its right border \(line 11\) on the same"),
])
def test_degenerate_lanelets_are_refused(tmp_path, load_map, kw, message):
    (tmp_path / "m.osm").write_text(_osm(**kw))
    with pytest.raises(ValueError, match=rf"m\.osm: {message}"):
        load_map(tmp_path / "m.osm")
