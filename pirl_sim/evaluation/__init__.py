"""Evaluation: protocols, the kinematic baselines and the direct regression, and the table and figure writers."""
