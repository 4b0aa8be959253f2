"""Encodings, one module each (its pure math, its settings and its registry record): the
frequency bands (posenc.py), dense grids (grid.py), hash grids (hash.py), TensoRF
factorisations (tensorf.py), spherical harmonics of directions (sh.py)."""
