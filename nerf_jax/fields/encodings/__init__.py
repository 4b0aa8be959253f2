"""Position encodings: positional (frequency) encoding, dense grids, hash grids, TensoRF
factorisations."""
