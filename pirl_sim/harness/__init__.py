"""Experiments: scenario x learner x protocol -> tidy rows, and the paper reproductions."""
