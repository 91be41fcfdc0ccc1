"""`aspod campaign`: a bench over a matrix of settings, one row per run, on Dask (docs/campaigns.md)."""
