"""The commands that run many cases and schemes and keep what they find: batch, campaigns on Dask,
coverage maps, FDI evaluation, baselines across commits, and the one gate ``check`` reads."""
