"""Where the tests find the INTERACTION dataset's tiny BSD-3 format sample.

The workplace keeps it in ``shared/data`` beside the repository, and its README asks that it not be copied into
the project. Without it the tests that need it skip, except under CI (``CI=true``), where ``shared/`` is always
laid beside the clone and a missing sample must fail.
"""

import os
from pathlib import Path

import pytest

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "interaction_format"
SAMPLE_MAP = DATA / "maps" / "TestScenarioForScripts.osm"
SAMPLE_DIR = DATA / "recorded_trackfiles" / "TestScenarioForScripts"
SAMPLE_TRACKS = SAMPLE_DIR / "vehicle_tracks_000.csv"

needs_sample = pytest.mark.skipif(
    not (SAMPLE_MAP.is_file() and SAMPLE_TRACKS.is_file())
    and os.environ.get("CI", "").strip().lower() not in ("1", "true", "yes"),
    reason=f"the shared INTERACTION sample is not beside the repository ({DATA})",
)
