"""Sweep configs that several test modules run or check (tests/engine, tests/cli): one copy of each TOML text and
of the helpers that parse them. Test modules ``from sweep_configs import ...`` (tests/conftest.py puts tests/ on
sys.path; under --import-mode=importlib a test module cannot import another test module).

- `TINY`: a small synthetic sweep (2 seeds x 2 protocols x 4 learner variants = 16 cells), parsed by `sweep_config`;
  its one experiment table, `TINY_EXPERIMENT`;
- `BAD`: configs derived from `TINY` that fail, each with the message that names its problem;
- `TINY_PASSAGE`: a passage sweep of paper and online cells, parsed and keyed by `passage_cells`;
- `TINY_LOG`: a one-cell synthetic sweep (TIRL, seed 0) for the command line's logging;
- `sweep_toml`: the TOML text of a sweep from its name, seeds and experiment tables (the layout of all of them).
"""

from __future__ import annotations

import tomllib

from pirl_sim.engine import parse_config


def sweep_toml(name: str | None, seeds, *experiments: str) -> str:
    """The TOML text of a sweep config: its ``name`` line (none where ``name`` is None) and ``seeds`` line, then an
    ``[[experiments]]`` table of each of ``experiments`` (the table's own lines: scenario, params, protocols,
    learners, ...), a blank line before each table."""
    head = ("" if name is None else f'name = "{name}"\n') + f"seeds = {list(seeds)}\n"
    return "\n" + head + "".join(f"\n[[experiments]]\n{table.strip()}\n" for table in experiments)


#: the experiment table of `TINY` (the Dask test's sweep runs it too): 2 protocols x 4 learner variants per seed
TINY_EXPERIMENT = """
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = ["tirl", { name = "pirl-gmm", params = { n_components = 2 } },
            { name = "pirl-knn", grid = { n_neighbors = [1, 4] } }]
"""
TINY = sweep_toml("tiny", [0, 1], TINY_EXPERIMENT)


def sweep_config(text: str = TINY, **kw):
    """The `pirl_sim.engine.config.SweepConfig` of the TOML ``text`` (`TINY` by default); ``kw`` to
    `parse_config`."""
    return parse_config(tomllib.loads(text), text=text, **kw)


#: {case: (config text, regex of the ValueError's message)}: configs that fail, each naming its problem
BAD = {
    "unknown top-level key": ("nme = 'x'\n" + TINY, r"unknown key\(s\) 'nme'; valid keys: name, description, seeds"),
    "unknown scenario": (TINY.replace('scenario = "synthetic"', 'scenario = "sumo-v9"'),
                         r"unknown scenario 'sumo-v9'; registered scenarios: .*passage.*synthetic"),
    "unknown learner": (TINY.replace('"tirl",', '"pirl-svm",'), r"unknown learner 'pirl-svm'; choose one of"),
    "unknown experiment key": (TINY.replace("protocols =", "protocol ="),
                               r"unknown key\(s\) 'protocol'; valid keys: scenario, label, seeds"),
    "unknown scenario parameter": (TINY.replace("n_train = 60", "n_tain = 60"),
                                   r"scenario 'synthetic': unknown parameter\(s\) 'n_tain'; valid parameters: "
                                   r"n_trajectories, n_train"),
    "unknown learner parameter": (TINY.replace("n_components = 2", "k = 2"),
                                  r"learner 'pirl-gmm': unknown parameter 'k'; valid parameters: .*n_components"),
    "unknown protocol kind": (TINY.replace('"paper",', '"offline",'), r"unknown protocol kind 'offline'"),
    "unknown protocol key": (TINY.replace("history_steps = 10", "history = 10"),
                             r"unknown key\(s\) 'history'; valid keys: kind, history_steps, horizon"),
    "empty value list": (TINY.replace("n_neighbors = [1, 4]", "n_neighbors = []"), r"empty grid: .*n_neighbors"),
    "no learners": (TINY.replace(TINY[TINY.index("learners ="):], "learners = []\n"),
                    r"empty grid: experiment 'synthetic' has no learner"),
    "no seeds": (TINY.replace("seeds = [0, 1]", "seeds = []"), r"empty grid: seeds is an empty list"),
    "no experiments": ('name = "x"\nseeds = [0]\n', r"empty grid: the sweep has no \[\[experiments\]\]"),
    "kNN k larger than the training set": (
        TINY.replace("n_neighbors = [1, 4]", "n_neighbors = [1, 61]"),
        r"PIRL-kNN \(k=61\) under the paper protocol: k = n_neighbors = 61 is larger than the training set "
        r"\(60 training trajectories"),
    "GMM k larger than the training set": (
        TINY.replace("n_components = 2", "n_components = 70"),
        r"k = n_components = 70 is larger than the training set"),
    "history longer than the trajectories": (
        TINY.replace("history_steps = 10", "history_steps = 50"),
        r"online \(history 50 steps\) protocol needs trajectories of at least 51 steps; the scenario's have at "
        r"most 50"),
    "window set by hand": (TINY.replace("n_components = 2", "n_components = 2, window = 5"),
                           r"'window' is set by the sweep"),
    "bad scenario value": (TINY.replace("n_train = 60", "n_train = 90"), r"scenario 'synthetic': n_train must be in"),
    "wrong type": (TINY.replace("n_train = 60", "n_train = 60.5"), r"'n_train' must be an integer, got 60.5"),
    "unknown style in a mix": (TINY.replace("n_train = 60 }", "n_train = 60, mix = { fast = 1.0 } }"),
                               r"mix names unknown style\(s\) \['fast'\]"),
    "two experiments with one label": (TINY + TINY[TINY.index("[[experiments]]"):],
                                       r"experiments 1 and 2 are both labelled 'synthetic': give one a label"),
    "rolling without horizon": (TINY.replace('"paper",', '{ kind = "rolling", history_steps = 5 },'),
                                r"the rolling protocol needs horizon >= 1"),
}


TINY_PASSAGE = sweep_toml("tiny online", [1], """
scenario = "passage"
params = { n_trajectories = 60, n_train = 45 }
protocols = ["paper", { kind = "online", history_steps = 10 }]
learners = [
    "tirl",
    { name = "pirl-gmm", label = "PIRL-GMM in weight space", params = { n_components = 3, space = "weights" } },
]
""")


def passage_cells():
    """({(protocol kind, learner label): cell}, config) of `TINY_PASSAGE`."""
    cfg = sweep_config(TINY_PASSAGE)
    return {(c.protocol["kind"], c.learner_label): c for c in cfg.cells}, cfg


TINY_LOG = sweep_toml("tiny-log", [0], """
scenario = "synthetic"
params = { n_trajectories = 80, n_train = 60 }
protocols = ["paper"]
learners = ["tirl"]
""")
