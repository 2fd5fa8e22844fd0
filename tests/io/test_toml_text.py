"""TOML files (pirl_sim.io.toml_text): a file that is not UTF-8 is an error naming it, whichever loader reads it."""

import re

import pytest


@pytest.mark.parametrize("loader", ["population", "scenario", "sweep"])
def test_a_binary_toml_error_names_the_file(tmp_path, loader):
    path = tmp_path / "binary.toml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n\x00\x00\xff")
    if loader == "population":
        from pirl_sim.scenarios.population_config import load_population as load
    elif loader == "scenario":
        from pirl_sim.scenarios.scenario_config import load_toml as load
    else:
        from pirl_sim.engine.config import load_config as load
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}: not valid TOML: .*not UTF-8"):
        load(path)
