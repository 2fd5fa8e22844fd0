"""The package itself (pirl_sim/__init__.py): it ships its inline type hints (py.typed)."""

from pathlib import Path


REPO = Path(__file__).resolve().parents[2]


def test_package_is_marked_typed():
    import tomllib
    from importlib.resources import files

    assert files("pirl_sim").joinpath("py.typed").is_file()
    data = tomllib.loads((REPO / "pyproject.toml").read_text(encoding="utf-8"))
    assert "py.typed" in data["tool"]["setuptools"]["package-data"]["pirl_sim"]  # shipped in wheels too
