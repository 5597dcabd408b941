"""balloon-study: design sweeps (simulator + estimator per case) on Dask distributed (docs/study.md)."""
