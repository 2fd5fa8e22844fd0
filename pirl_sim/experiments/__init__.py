"""Experiments: each a kind the engine runs (its parameters, data and cell runner) beside its report template."""
