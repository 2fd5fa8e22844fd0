"""Track tables of scenes (pirl_sim.viz.frames): bad tables refused with the reason."""

import numpy as np
import pandas as pd
import pytest

from pirl_sim.viz import SceneView, TrackFrames

from viz_testdata import straight_tracks


def test_bad_track_tables_are_rejected_with_the_reason():
    tracks = straight_tracks(2, 5)
    with pytest.raises(ValueError, match=r"lacks column\(s\) \['psi_rad'\]"):
        TrackFrames(tracks.drop(columns="psi_rad"))
    bad = tracks.copy()
    bad.loc[3, "x"] = np.nan
    with pytest.raises(ValueError, match="'x' has values that are not finite"):
        TrackFrames(bad)
    with pytest.raises(ValueError, match="appears more than once"):
        TrackFrames(pd.concat([tracks, tracks.iloc[:1]]))
    with pytest.raises(ValueError, match="no rows"):
        TrackFrames(tracks.iloc[:0])
    with pytest.raises(TypeError, match="DataFrame"):
        TrackFrames(tracks.to_numpy())
    with pytest.raises(ValueError, match="extent must be"):
        SceneView(tracks, extent=(1, 0, 0, 1))
    with pytest.raises(ValueError, match="size_px width must be an integer"):
        SceneView(tracks, size_px=(3, 200))
