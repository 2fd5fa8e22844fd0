"""Hypothesis pieces of the fuzz tests of TOML configs (sweep configs, population configs): one copy of the settings,
the value strategies and the mutation of a parsed config; and, for those of every file reader (TOML configs, track
files, maps), `read_or_error_naming_it`. Test modules ``from toml_fuzz import ...`` after their
``pytest.importorskip("hypothesis")`` (tests/conftest.py puts tests/ on sys.path)."""

from __future__ import annotations

from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

#: the fuzz tests' settings: 60 examples, no deadline (a config check may load a scenario)
FUZZ = settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture,
                                                                       HealthCheck.too_slow])


TOML_SCALAR = st.one_of(st.booleans(), st.integers(-2**40, 2**40), st.floats(allow_nan=True, allow_infinity=True),
                        st.text(max_size=8), st.sampled_from(["full", "weird", "poisson", "regular", "tirl",
                                                              "pirl-gmm", "paper", "online", "synthetic"]))
TOML_VALUE = st.recursive(TOML_SCALAR, lambda inner: st.one_of(st.lists(inner, max_size=3),
                                                               st.dictionaries(st.text(max_size=6), inner,
                                                                               max_size=3)), max_leaves=6)


def mutated_mapping(draw, base, keys: list[str]):
    """``base`` (a dict, changed in place) with some values replaced, some keys deleted, an unknown key added."""
    for _ in range(draw(st.integers(1, 3))):
        kind = draw(st.sampled_from(["replace", "replace", "delete", "add"]))
        key = draw(st.sampled_from(keys))
        if kind == "replace":
            base[key] = draw(TOML_VALUE)
        elif kind == "delete":
            base.pop(key, None)
        else:
            base[draw(st.text(min_size=1, max_size=6))] = draw(TOML_VALUE)
    return base


def read_or_error_naming_it(read, path):
    """(True, ``read(path)``), or (False, None) where ``read`` raises a ValueError: the error must name ``path`` (an
    assertion fails where it does not)."""
    try:
        return True, read(path)
    except ValueError as exc:
        assert str(path) in str(exc)
        return False, None
