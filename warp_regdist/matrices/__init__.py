"""Distance matrices from batched single-source rows: blocks solved here or on a Dask cluster,
stored in memory or on disk, resumable."""
