"""Tracks (pirl_sim.viz.tracks): each drawn where its coordinates are, in its legend colour."""

from pirl_sim.viz import color_rows, data_to_pixel, draw_tracks, figure_to_array, new_figure

from viz_testdata import has_color_near, straight_tracks


SMALL = (320, 240)


def test_each_track_is_drawn_where_its_coordinates_are_in_its_legend_colour():
    tracks = straight_tracks(3, 30)
    styles = {1: "calm", 2: "normal", 3: "aggressive"}
    fig = new_figure(SMALL)
    ax = fig.add_subplot()
    draw_tracks(ax, tracks, color_by=styles, label="style", linewidth=3.0)
    ax.set_xlim(-2, 17)
    ax.set_ylim(-5, 25)
    img = figure_to_array(fig)
    colors = color_rows(tracks, styles)
    legend = dict(colors.legend)
    assert set(legend) == {"calm", "normal", "aggressive"}
    for track_id, style in styles.items():
        mid = (7.0, 10.0 * (track_id - 1))
        assert has_color_near(img, data_to_pixel(ax, mid), legend[style], radius=1, tol=10), style
    # and not between the tracks
    between = data_to_pixel(ax, (7.0, 5.0))
    for rgba in legend.values():
        assert not has_color_near(img, between, rgba, radius=2, tol=60)
    assert ax.get_legend() is not None
