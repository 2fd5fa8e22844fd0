"""Scenario sweeps: config grids, local processes or Dask, a resumable result store, reports."""
