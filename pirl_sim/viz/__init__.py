"""Scene drawing: roads, vehicles, tracks, predictions and animations, drawn off-screen with matplotlib's Agg.

Import it where drawing is needed (it imports matplotlib); nothing here touches pyplot or the global backend.

- :mod:`~pirl_sim.viz.road`, :mod:`~pirl_sim.viz.road_sources`: a :class:`Road` from a Lanelet2 map, a SUMO
  network or highway-env's roundabout, and :func:`draw_road`;
- :mod:`~pirl_sim.viz.scene`: :func:`draw_scene` (vehicles as oriented boxes at a frame) and the reusable
  :class:`SceneView`; :mod:`~pirl_sim.viz.live`: :class:`LiveView`, a running simulation's vehicles on its road;
  :mod:`~pirl_sim.viz.tracks`: :func:`draw_tracks` coloured by a column, and
  :func:`draw_recording` (:mod:`~pirl_sim.viz.overview`), every track of a recording on one figure;
- :mod:`~pirl_sim.viz.prediction`: :func:`draw_prediction` of a :class:`PredictionWindow`;
- :mod:`~pirl_sim.viz.animation`: frames as arrays and ``.gif``/``.mp4`` files;
- :mod:`~pirl_sim.viz.raster`: figures to ``(H, W, 3)`` arrays and data points to pixels.
"""

from .animation import (
    animate_predictions,
    animate_scene,
    frame_schedule,
    iter_prediction_frames,
    iter_scene_frames,
    render_prediction_frames,
    render_scene_frames,
)
from .colors import color_rows, distinct_colors
from .frames import SCENE_COLUMNS, TrackFrames
from .live import LiveView
from .overview import draw_recording
from .prediction import PredictionView, PredictionWindow, draw_prediction
from .raster import data_to_pixel, figure_to_array, new_figure
from .road import Road, draw_road
from .road_sources import road_from_highway, road_from_lanelet2, road_from_sumo
from .scene import SceneView, draw_scene
from .tracks import draw_tracks
from .vehicles import box_corners
from .writers import FORMATS

__all__ = [
    "Road",
    "draw_road",
    "road_from_lanelet2",
    "road_from_sumo",
    "road_from_highway",
    "TrackFrames",
    "SCENE_COLUMNS",
    "SceneView",
    "LiveView",
    "draw_scene",
    "draw_tracks",
    "draw_recording",
    "box_corners",
    "color_rows",
    "distinct_colors",
    "PredictionWindow",
    "PredictionView",
    "draw_prediction",
    "frame_schedule",
    "iter_scene_frames",
    "render_scene_frames",
    "animate_scene",
    "iter_prediction_frames",
    "render_prediction_frames",
    "animate_predictions",
    "FORMATS",
    "new_figure",
    "figure_to_array",
    "data_to_pixel",
]
