"""Coloured point clouds as PLY files (the sparse points of a capture, `sparse_pc.ply`).

points: float64 [P, 3]; colors: uint8 [P, 3].
Writes ASCII PLY (what nerfstudio writes); reads ASCII and binary little-endian vertex lists.
"""

import numpy as np

from nerf_jax.data.dataset import DataError

_PLY_TYPES = {"char": "i1", "uchar": "u1", "short": "i2", "ushort": "u2", "int": "i4",
              "uint": "u4", "float": "f4", "double": "f8", "int8": "i1", "uint8": "u1",
              "int16": "i2", "uint16": "u2", "int32": "i4", "uint32": "u4", "float32": "f4",
              "float64": "f8"}


def write_ply(path, points, colors):
  """Write `points` and their `colors` as an ASCII PLY file."""
  header = ["ply", "format ascii 1.0", f"element vertex {len(points)}",
            "property float x", "property float y", "property float z",
            "property uchar red", "property uchar green", "property uchar blue", "end_header"]
  with open(path, "w") as f:
    f.write("\n".join(header) + "\n")
    for p, c in zip(np.asarray(points, np.float64), np.asarray(colors, np.uint8)):
      f.write(f"{p[0]:.6f} {p[1]:.6f} {p[2]:.6f} {c[0]} {c[1]} {c[2]}\n")


def _header(f, path):
  """(format, vertex count, [(name, dtype)]) of the vertex element; f is at the data."""
  if f.readline().strip() != b"ply":
    raise DataError(f"{path}: not a PLY file")
  fmt, count, props, element = None, 0, [], None
  for line in iter(f.readline, b""):
    words = line.decode("ascii", "replace").split()
    if not words or words[0] in ("comment", "obj_info"):
      continue
    if words[0] == "end_header":
      break
    if words[0] == "format":
      fmt = words[1]
    elif words[0] == "element":
      element = words[1]
      if element == "vertex":
        count = int(words[2])
    elif words[0] == "property" and element == "vertex":
      if words[1] == "list" or words[1] not in _PLY_TYPES:
        raise DataError(f"{path}: unsupported vertex property {' '.join(words[1:])}")
      props.append((words[2], _PLY_TYPES[words[1]]))
  else:
    raise DataError(f"{path}: PLY header has no end_header")
  return fmt, count, props


def read_ply(path):
  """(points float64 [P, 3], colors uint8 [P, 3] or None) of a PLY file's vertices."""
  try:
    with open(path, "rb") as f:
      fmt, count, props = _header(f, path)
      names = [n for n, _ in props]
      if not {"x", "y", "z"} <= set(names):
        raise DataError(f"{path}: PLY vertices lack x, y, z (have {', '.join(names)})")
      if fmt == "ascii":
        table = np.loadtxt(f, ndmin=2, max_rows=count) if count else np.zeros((0, len(props)))
        column = lambda n: table[:, names.index(n)]
      elif fmt == "binary_little_endian":
        table = np.fromfile(f, np.dtype([(n, "<" + t) for n, t in props]), count)
        column = lambda n: table[n]
      else:
        raise DataError(f"{path}: PLY format {fmt!r} is not supported (ascii, "
                        "binary_little_endian)")
  except OSError as e:
    raise DataError(f"{path}: cannot read ({e.strerror})") from None
  except ValueError as e:  # numbers that do not parse, a short file
    if isinstance(e, DataError):
      raise
    raise DataError(f"{path}: malformed PLY data ({e})") from None
  if len(column("x")) != count:
    raise DataError(f"{path}: PLY has {len(column('x'))} vertices, header says {count}")
  points = np.stack([column(n) for n in "xyz"], -1).astype(np.float64)
  colors = None
  if {"red", "green", "blue"} <= set(names):
    colors = np.stack([column(n) for n in ("red", "green", "blue")], -1).astype(np.uint8)
  return points, colors
