"""Episodes on disk: one HDF5 file per episode (see store.py for the format and why), windows for sequence
models, and importers for other pipelines' demonstration formats."""
