"""Recording tables (pirl_sim.io.tables): a bad value named by its file, line and column."""

import numpy as np
import pytest

from pirl_sim.io.tables import read_csv_table


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
