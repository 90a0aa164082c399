"""Results at rest: the store's atomic files, tidy views (xarray, pandas, netCDF, Parquet), the
provenance manifest, and stored results read back for notebooks."""
