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


def _loader(name):
    if name == "population":
        from pirl_sim.scenarios.population_config import load_population as load
    elif name == "scenario":
        from pirl_sim.scenarios.scenario_config import load_toml as load
    else:
        from pirl_sim.engine.config import load_config as load
    return load


@pytest.mark.parametrize("loader", ["population", "scenario", "sweep"])
@pytest.mark.parametrize("text", ["x = " + "[" * 500 + "]" * 500, "x = " + "[" * 100 + "1" + "]" * 100,
                                  "[" + ".".join(["t"] * 100) + "]\nx = 1"],
                         ids=["arrays-500", "arrays-100", "tables-100"])
def test_a_toml_nested_too_deeply_is_a_value_error_naming_the_file_and_the_limit(tmp_path, loader, text):
    from pirl_sim.io.toml_text import MAX_DEPTH

    path = tmp_path / "deep.toml"
    path.write_text(text + "\n")
    with pytest.raises(ValueError, match=rf"{re.escape(str(path))}: arrays or tables nested deeper than "
                                         rf"{MAX_DEPTH} levels"):
        _loader(loader)(path)
