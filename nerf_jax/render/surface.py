"""Surface export: marching cubes over the density field, written as a vertex-coloured PLY.

The density sigma (1 / scene unit) is sampled at the lattice points of the box
[-bound, bound]^3, `resolution` points per side (voxel size 2·bound / (resolution - 1)); the
surface is the iso-surface sigma = threshold. Names:
  vertices: float32 [V, 3], world positions (scene units)
  faces:    int32 [F, 3], vertex indices of each triangle, counter-clockwise seen from outside
  normals:  float32 [V, 3], unit outward normals (towards lower density)
  colors:   uint8 [V, 3], the radiance field's colour seen from outside along -normal
"""

import jax
import numpy as np
from skimage import measure


def sample_grid(fn, bound, resolution, chunk=65536):
  """fn on the lattice of [-bound, bound]^3: float32 [R, R, R], indexed [x, y, z].

  fn: points float32 [chunk, 3] -> float32 [chunk]; called on fixed-size padded chunks, so a
  jitted fn compiles once and memory does not grow with the resolution beyond the grid itself.
  """
  axis = np.linspace(-bound, bound, resolution, dtype=np.float32)
  total = resolution ** 3
  out = np.empty(total, np.float32)
  for start in range(0, total, chunk):
    index = np.minimum(np.arange(start, start + chunk), total - 1)  # pad with the last point
    i, j, k = np.unravel_index(index, (resolution,) * 3)
    values = np.asarray(fn(np.stack([axis[i], axis[j], axis[k]], -1)))
    out[start:start + chunk] = values[:min(chunk, total - start)]
  return out.reshape((resolution,) * 3)


def marching_cubes(density, threshold, bound):
  """The iso-surface density = threshold of a lattice from `sample_grid`.

  density: float32 [R, R, R]. Returns (vertices, faces, normals) in world units (see module).
  Raises ValueError when the threshold is outside the range of the density (no surface).
  """
  low, high = float(density.min()), float(density.max())
  if not low < threshold < high:
    raise ValueError(f"--threshold={threshold:g}: no surface, the density ranges over "
                     f"[{low:.4g}, {high:.4g}] in the box; pick a threshold inside it")
  spacing = 2.0 * bound / (density.shape[0] - 1)
  # 'ascent': the object is where the density exceeds the threshold; faces then wind
  # counter-clockwise seen from outside and the normals point outwards (down the gradient).
  verts, faces, normals, _ = measure.marching_cubes(
      density, level=threshold, spacing=(spacing,) * 3, gradient_direction="ascent")
  return ((verts - bound).astype(np.float32), faces.astype(np.int32),
          normals.astype(np.float32))


def field_functions(field, params):
  """Jitted (density_fn, color_fn) of a network's `params` in `field` (field.Field).

  density_fn(points float32 [C, 3]) -> sigma float32 [C].
  color_fn(points float32 [C, 3], viewdirs float32 [C, 3] unit) -> rgb float32 [C, 3].
  """
  params = jax.device_put(params)  # an argument, not a constant
  density = jax.jit(lambda params, points: field.density(params)(points))
  color = jax.jit(lambda params, points, viewdirs: field.at_points(params, points, viewdirs)[0])
  return (lambda points: density(params, points)), (lambda p, d: color(params, p, d))


def vertex_colors(color_fn, vertices, normals, chunk=65536):
  """uint8 [V, 3]: the colour of each vertex seen from outside, along -normal."""
  colors = np.empty((len(vertices), 3), np.float32)
  for start in range(0, len(vertices), chunk):
    index = np.minimum(np.arange(start, start + chunk), len(vertices) - 1)
    rgb = np.asarray(color_fn(vertices[index], -normals[index]))
    colors[start:start + chunk] = rgb[:min(chunk, len(vertices) - start)]
  return (np.clip(colors, 0.0, 1.0) * 255.0 + 0.5).astype(np.uint8)


def extract(field, params, bound, resolution=128, threshold=50.0, chunk=65536):
  """The coloured surface of a trained network `params` of `field` (field.Field): dict
  vertices, faces, normals, colors (see the module docstring).

  bound: half-size of the box. threshold: density (1 / scene unit) of the surface.
  """
  if resolution < 2:
    raise ValueError(f"--resolution={resolution}: need at least 2 lattice points per side")
  density_fn, color_fn = field_functions(field, params)
  density = sample_grid(density_fn, bound, resolution, chunk)
  vertices, faces, normals = marching_cubes(density, threshold, bound)
  return {"vertices": vertices, "faces": faces, "normals": normals,
          "colors": vertex_colors(color_fn, vertices, normals, chunk)}


def write_ply(path, vertices, faces, colors=None):
  """A binary little-endian PLY: vertices float32 [V, 3], faces int [F, 3], colors uint8 [V, 3]."""
  fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
  if colors is not None:
    fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
  vertex = np.empty(len(vertices), dtype=fields)
  for axis, name in enumerate("xyz"):
    vertex[name] = vertices[:, axis]
  if colors is not None:
    for channel, name in enumerate(("red", "green", "blue")):
      vertex[name] = colors[:, channel]
  face = np.empty(len(faces), dtype=[("n", "u1"), ("v", "<i4", (3,))])
  face["n"], face["v"] = 3, faces
  types = {"<f4": "float", "u1": "uchar"}
  header = ["ply", "format binary_little_endian 1.0", f"element vertex {len(vertices)}"]
  header += [f"property {types[t]} {name}" for name, t in fields]
  header += [f"element face {len(faces)}", "property list uchar int vertex_indices",
             "end_header"]
  with open(path, "wb") as f:
    f.write(("\n".join(header) + "\n").encode("ascii"))
    f.write(vertex.tobytes())
    f.write(face.tobytes())


def read_ply(path):
  """(vertices float32 [V, 3], faces int32 [F, 3], colors uint8 [V, 3] or None) of a PLY that
  `write_ply` wrote."""
  with open(path, "rb") as f:
    data = f.read()
  end = data.index(b"end_header\n") + len(b"end_header\n")
  lines = data[:end].decode("ascii").splitlines()
  num_vertices = int(next(l for l in lines if l.startswith("element vertex")).split()[-1])
  num_faces = int(next(l for l in lines if l.startswith("element face")).split()[-1])
  has_color = any(l.endswith(" red") for l in lines)
  fields = [("x", "<f4"), ("y", "<f4"), ("z", "<f4")]
  if has_color:
    fields += [("red", "u1"), ("green", "u1"), ("blue", "u1")]
  vertex = np.frombuffer(data, dtype=fields, count=num_vertices, offset=end)
  face = np.frombuffer(data, dtype=[("n", "u1"), ("v", "<i4", (3,))], count=num_faces,
                       offset=end + vertex.nbytes)
  vertices = np.stack([vertex[n] for n in "xyz"], -1)
  colors = np.stack([vertex[n] for n in ("red", "green", "blue")], -1) if has_color else None
  return vertices, face["v"].astype(np.int32), colors
