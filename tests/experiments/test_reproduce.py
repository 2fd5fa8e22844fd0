"""The reproductions (pirl_sim.experiments.reproduce): the committed results/<name> tables are the committed default
sweep's seed-0 cells."""

from pathlib import Path

import pytest


@pytest.mark.parametrize("name", ["synthetic", "passage"])
def test_committed_reproductions_are_the_committed_sweeps_seed_0_cells(name):
    """results/<name>/table.csv and knn_k.csv are what the report template makes of the committed default sweep's
    cells (results/sweep/cells of the code version in its sweep.json, matched by their full configuration): the
    README's tables of both come from one path."""
    import json

    from pirl_sim.engine.presets import preset_config
    from pirl_sim.experiments.reproduce import report_tables
    from pirl_sim.engine.config import canonical_json
    from pirl_sim.engine.run import assemble_table

    repo = Path(__file__).resolve().parents[2]
    version = json.loads((repo / "results" / "sweep" / "sweep.json").read_text())["code_version"]
    by_spec = {}
    for path in (repo / "results" / "sweep" / "cells").glob("*.json"):
        record = json.loads(path.read_text())
        if record["code_version"] == version:  # the sweep's own cells, not stale ones
            by_spec[canonical_json(record["cell"])] = record
    config = preset_config(name)
    keys = [c.key("committed") for c in config.cells]
    records = {k: by_spec[canonical_json(c.spec())] for k, c in zip(keys, config.cells)}
    table, ktable = report_tables(name, assemble_table(config, keys, records))
    committed = repo / "results" / name
    assert table.to_csv(index=False, float_format="%.6g") == (committed / "table.csv").read_text()
    assert ktable.to_csv(index=False, float_format="%.6g") == (committed / "knn_k.csv").read_text()
