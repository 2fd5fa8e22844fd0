"""Speed of drawing a recording's animation: frames per second, extrapolated to a 10-minute recording.

    OPENBLAS_NUM_THREADS=1 python benchmarks/bench_viz.py [--span 60] [--repeats 3] [--tracks T.csv --map M.osm]

Workload: a recording at 10 frames per second, drawn at fps = 10 (every recorded frame) over ``--span``
seconds, 800 x 600 px, vehicles coloured by speed with 2 s trails, the road beneath. By default the recording
is generated (a 10-minute roundabout-like scene: a ring of radius 25 m with four arms, one vehicle entering
every 1.2 s, ~25 on the road at once, 10 min of frames); ``--tracks``/``--map`` draw a real INTERACTION
recording and its Lanelet2 map instead (e.g. DR_USA_Roundabout_FT, ~12 vehicles at once).

Measured, each a median of ``--repeats`` rounds: frames as arrays (``iter_scene_frames``), and written as MP4
(``animate_scene``, ffmpeg's libx264) when ffmpeg is on PATH. Target: the 10-minute animation (6,000 frames)
takes less than its real time, 600 s, i.e. more than 10 frames per second; the time for 6,000 frames is
extrapolated from the measured rate. The load average is printed before and after.

The generated vehicles follow fixed paths at constant speeds and may overlap: they load the drawing, they are
not traffic.
"""

from __future__ import annotations

import argparse
import os
import shutil
import statistics
import tempfile
import time

import numpy as np
import pandas as pd

from pirl_sim.viz import Road, animate_scene, iter_scene_frames
from pirl_sim.viz.road_sources import offset_polyline

TARGET_S = 600.0  # [s] a 10-minute recording's real time
FPS = 10.0  # [frames/s] of the animation, one per recorded frame
RING_R = 25.0  # [m] ring centre line radius of the generated scene
LANE_W = 4.0  # [m]


def generated_recording(minutes: float = 10.0, *, arrival_s: float = 1.2, seed: int = 0) -> pd.DataFrame:
    """A roundabout-like recording: vehicles enter from four arms, drive part of the ring, leave by an arm."""
    rng = np.random.default_rng(seed)
    n_frames = int(minutes * 600)
    rows = []
    for k, t_in in enumerate(np.arange(0.0, minutes * 60.0, arrival_s)):
        arm_in, turns = rng.integers(4), rng.integers(1, 4)
        speed = rng.uniform(4.0, 9.0)  # [m/s]
        a0 = arm_in * np.pi / 2
        a1 = a0 + turns * np.pi / 2
        approach = 40.0
        s_total = approach + RING_R * (a1 - a0) + approach
        s = np.arange(0.0, s_total, speed * 0.1)
        x, y, psi = np.empty_like(s), np.empty_like(s), np.empty_like(s)
        entry = s < approach
        ring = (s >= approach) & (s < approach + RING_R * (a1 - a0))
        leave = ~entry & ~ring
        r_in = RING_R + approach - s[entry]
        x[entry], y[entry], psi[entry] = r_in * np.cos(a0), r_in * np.sin(a0), a0 + np.pi
        ang = a0 + (s[ring] - approach) / RING_R
        x[ring], y[ring], psi[ring] = RING_R * np.cos(ang), RING_R * np.sin(ang), ang + np.pi / 2
        r_out = RING_R + s[leave] - approach - RING_R * (a1 - a0)
        x[leave], y[leave], psi[leave] = r_out * np.cos(a1), r_out * np.sin(a1), np.full(leave.sum(), a1)
        frame0 = int(round(t_in * 10)) + 1
        frames = frame0 + np.arange(len(s))
        keep = frames <= n_frames
        n = int(keep.sum())
        rows.append(pd.DataFrame({
            "track_id": k + 1, "frame_id": frames[keep], "timestamp_ms": 100 * frames[keep], "agent_type": "car",
            "x": x[keep], "y": y[keep], "vx": speed * np.cos(psi[keep]), "vy": speed * np.sin(psi[keep]),
            "psi_rad": psi[keep], "length": np.full(n, 4.5), "width": np.full(n, 1.8)}))
    return pd.concat(rows, ignore_index=True)


def generated_road() -> Road:
    """The generated scene's road: the ring's two borders and four two-way arms."""
    ang = np.linspace(0.0, 2 * np.pi, 181)
    circle = np.column_stack([np.cos(ang), np.sin(ang)])
    boundaries, styles, centre = [circle * (RING_R + LANE_W / 2), circle * (RING_R - LANE_W / 2)], ["solid", "solid"], \
        [circle * RING_R]
    for i in range(4):
        d = np.array([np.cos(i * np.pi / 2), np.sin(i * np.pi / 2)])
        axis = np.array([d * (RING_R + LANE_W / 2), d * (RING_R + 45.0)])
        for off, style in ((-LANE_W, "solid"), (0.0, "dashed"), (LANE_W, "solid")):
            boundaries.append(offset_polyline(axis, off))
            styles.append(style)
        centre.append(axis)
    return Road(tuple(boundaries), tuple(styles), tuple(centre), source="generated roundabout")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--span", type=float, default=60.0, help="seconds of the recording drawn per round")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--tracks", help="an INTERACTION vehicle_tracks_*.csv instead of the generated recording")
    ap.add_argument("--map", help="its Lanelet2 .osm map (with --tracks)")
    args = ap.parse_args(argv)
    if args.tracks:
        from pirl_sim.io.interaction import read_tracks
        from pirl_sim.viz import road_from_lanelet2

        tracks = read_tracks(args.tracks)
        road = road_from_lanelet2(args.map) if args.map else None
        what = f"{os.path.basename(args.tracks)}"
    else:
        tracks, road, what = generated_recording(), generated_road(), "generated 10-minute roundabout"
    t0 = tracks.timestamp_ms.min() / 1000.0
    start, end = t0 + 60.0, t0 + 60.0 + args.span  # skip the first minute (the generated scene fills up)
    per_frame = tracks.groupby("frame_id").size()
    options = dict(road=road, color_by="speed", trail_s=2.0, size_px=(800, 600))
    print(f"{what}: {tracks.track_id.nunique()} tracks, {len(per_frame)} frames, "
          f"{per_frame.mean():.1f} vehicles per frame on average; drawing {args.span:g} s at {FPS:g} fps, "
          f"{options['size_px'][0]}x{options['size_px'][1]} px, OPENBLAS_NUM_THREADS="
          f"{os.environ.get('OPENBLAS_NUM_THREADS', 'unset')}, load average {os.getloadavg()[0]:.1f}")
    n = int(round(args.span * FPS))
    workloads = {"frames as arrays": lambda: sum(1 for _ in iter_scene_frames(tracks, start_s=start, end_s=end,
                                                                           fps=FPS, **options))}
    tmp = tempfile.mkdtemp(prefix="bench_viz_")
    if shutil.which("ffmpeg"):
        workloads["MP4 file (ffmpeg)"] = lambda: animate_scene(tracks, os.path.join(tmp, "scene.mp4"), start_s=start,
                                                               end_s=end, fps=FPS, **options)
    else:
        print("ffmpeg not on PATH: the MP4 workload is skipped")
    times = {name: [] for name in workloads}
    try:
        for _ in range(args.repeats):
            for name, fn in workloads.items():  # interleaved, so that other load hits all alike
                t = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    for name, ts in times.items():
        fps = n / statistics.median(ts)
        full = 6000 / fps
        print(f"  {name:18s}: {fps:6.1f} frames/s (median of {len(ts)}: {', '.join(f'{t:.1f}' for t in ts)} s for "
              f"{n} frames) -> 10-minute animation ~{full:.0f} s (target < {TARGET_S:.0f} s: "
              f"{'met' if full < TARGET_S else 'NOT met'})")
    print(f"load average after: {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
