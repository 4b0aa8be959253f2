"""The precision policy (nerf_jax/backend/precision.py): geometry, data and metrics in full float32
on every backend, checked on the jaxpr; the CPU emulation of a GPU's TF32 matmuls and approximate
division bites where the policy is not followed; the networks' setting; deterministic ops."""

import functools
import os
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.backend import determinism, precision
from nerf_jax.cameras import pose_refinement, rays
from nerf_jax.evaluate import metrics
from nerf_jax.render import compositing
from nerf_jax.samplers import visual_hull
from nerf_jax.data.scenes import builtin, tracer
from nerf_jax.fields.networks import mlp
from nerf_jax.fields.networks.mlp import NerfMLP
from nerf_jax.fields.protocol import NetworkSettings

EMULATING_TF32 = jax.default_backend() != "cpu" or "tf32" in precision.emulated()
EMULATING_DIV = jax.default_backend() != "cpu" or "div" in precision.emulated()
POSE = rays.pose_spherical(30.0, -40.0, 4.0)


def _products(jaxpr):
  """Every dot_general and conv_general_dilated equation of `jaxpr`, sub-jaxprs included."""
  found = []
  for eqn in jaxpr.eqns:
    if eqn.primitive.name in ("dot_general", "conv_general_dilated"):
      found.append(eqn)
    for value in eqn.params.values():
      for sub in value if isinstance(value, (tuple, list)) else (value,):
        inner = getattr(sub, "jaxpr", sub)
        if hasattr(inner, "eqns"):
          found += _products(inner)
  return found


def _geometry():
  """(name, function, arguments) of each geometry or metric computation with a matmul, an
  einsum or a convolution."""
  rng = np.random.default_rng(0)
  image = rng.uniform(size=(16, 16, 3)).astype(np.float32)
  rgb, sigma = rng.uniform(size=(4, 8, 3)), rng.uniform(size=(4, 8))
  t = np.broadcast_to(np.linspace(2.0, 6.0, 9), (4, 9))
  scene = builtin.get_scene("glossy")
  pixels = jnp.zeros((4,), jnp.int32)
  return [
      ("rays.get_rays", lambda c2w: rays.get_rays(8, 8, 10.0, c2w), (POSE,)),
      ("rays.camera_rays (NDC)", lambda c2w: rays.camera_rays(
          8, 8, (10.0, 10.0, 4.0, 4.0), c2w, 1.0, 1e10, use_ndc=True), (POSE,)),
      ("compositing.composite", compositing.composite, (rgb, sigma, t)),
      ("pose_refinement.corrected", pose_refinement.corrected, (POSE, np.full(6, 0.1))),
      ("visual_hull.project", lambda p, c2w: visual_hull.project(p, c2w, (10.0, 10.0, 4.0, 4.0)),
       (jnp.ones((5, 3)), POSE)),
      ("metrics.ssim", metrics.ssim, (image, image[::-1])),
      ("scenes.tracer", functools.partial(tracer._render_pixels, scene, 2),  # pylint: disable=protected-access
       (jnp.broadcast_to(jnp.asarray(POSE[:3]), (4, 3, 4)), pixels, pixels, 8, 8, 10.0, 0.5,
        2.0, 6.0)),
  ]


@pytest.mark.parametrize("name, fn, args", _geometry(), ids=[g[0] for g in _geometry()])
def test_geometry_products_are_at_highest_precision(name, fn, args):
  products = _products(jax.make_jaxpr(fn)(*args).jaxpr)
  assert products, f"{name} has no matmul: this test no longer covers it"
  for eqn in products:
    assert eqn.params["precision"] in ((precision.HIGHEST, precision.HIGHEST),
                                       precision.HIGHEST), (name, eqn)


def test_the_jaxpr_check_sees_a_default_precision_product():
  # The check above fails for a product that forgets the helper.
  slipped = lambda c2w, d: jnp.einsum("ij,...j->...i", c2w[:3, :3], d)
  eqn, = _products(jax.make_jaxpr(slipped)(POSE, jnp.ones((4, 3))).jaxpr)
  assert eqn.params["precision"] not in ((precision.HIGHEST, precision.HIGHEST),
                                         precision.HIGHEST)


def _world_directions_f64(height, width, focal, c2w):
  i, j = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
  cam = np.stack([(i - 0.5 * width) / focal, -(j - 0.5 * height) / focal, -np.ones_like(i)], -1)
  return cam @ np.asarray(c2w, np.float64)[:3, :3].T


@pytest.mark.skipif(not EMULATING_TF32, reason="a CPU without NERF_JAX_EMULATE=tf32")
def test_a_camera_turned_at_default_precision_is_caught():
  # 400 px at the blender focal length: the TF32 turn of a pixel's direction is off by ~1e-4
  # (~0.05 px), the helper's by float32 rounding. Under the emulation (the tests' default on a
  # CPU) or on a GPU, a geometry function that forgets the helper fails a 1e-5 tolerance.
  height = width = 400
  focal, c2w = 555.5, jnp.asarray(POSE)
  truth = _world_directions_f64(height, width, focal, POSE)
  _, directions = jax.jit(rays.get_rays, static_argnums=(0, 1))(height, width, focal, c2w)
  np.testing.assert_allclose(directions, truth, atol=1e-5)
  cam = rays.pixel_directions(height, width, focal, focal, 0.5 * width, 0.5 * height)
  slipped = jax.jit(lambda d, c: jnp.einsum("ij,...j->...i", c[:3, :3], d))(cam, c2w)
  assert np.max(np.abs(np.asarray(slipped) - truth)) > 1e-5


@pytest.mark.skipif(not EMULATING_DIV, reason="a CPU without NERF_JAX_EMULATE=div")
def test_approximate_division_rounds_x_over_x_above_one():
  # What the numerics must survive: x/x is not always 1 (the linf contraction's old bound).
  x = np.random.default_rng(1).uniform(0.1, 10.0, 10_000).astype(np.float32)
  q = np.asarray(jax.jit(lambda a: a / a)(x))
  assert np.any(q > 1.0)
  assert np.all(np.abs(q - 1.0) <= 2.0 ** -22)  # within 2 ulps of 1


def test_emulated_division_is_within_four_ulps_and_exact_for_powers_of_two():
  x = np.random.default_rng(2).uniform(-10.0, 10.0, (2, 10_000)).astype(np.float32)
  q = np.asarray(jax.jit(lambda a, b: a / b)(x[0], x[1]), np.float64)
  exact = x[0].astype(np.float64) / x[1]
  assert np.all(np.abs(q - exact) <= 4.0 * np.spacing(np.abs(exact).astype(np.float32)))
  np.testing.assert_array_equal(jax.jit(lambda a: a / 4.0)(x[0]), x[0] * 0.25)


def test_host_operands_stay_on_the_host_in_their_dtype():
  a = np.random.default_rng(3).normal(size=(3, 3))
  out = precision.matmul(a, a)
  assert isinstance(out, np.ndarray) and out.dtype == np.float64
  np.testing.assert_array_equal(out, a @ a)
  assert isinstance(precision.einsum("ij,j->i", jnp.asarray(a, jnp.float32), a[0]), jax.Array)


def test_network_precision_setting():
  assert precision.network_precision("default") is None
  assert precision.network_precision("highest") == precision.HIGHEST
  with pytest.raises(ValueError, match="model.matmul_precision"):
    precision.network_precision("tf32")
  # The setting reaches every Dense layer of the network.
  net = NerfMLP(mlp.Settings(depth=2, skip_layers=()),
                NetworkSettings(width=8, matmul_precision="highest"))
  x = jnp.ones((2, 5))
  params = net.init(jax.random.PRNGKey(0), x)
  products = _products(jax.make_jaxpr(lambda p: net.apply(p, x))(params).jaxpr)
  assert len(products) == 3
  assert all(e.params["precision"] == (precision.HIGHEST, precision.HIGHEST) for e in products)


@pytest.mark.slow  # a process
def test_tests_run_with_deterministic_ops_inherited_by_subprocesses():
  assert determinism.enabled()
  out = subprocess.run([sys.executable, "-c", "from nerf_jax.backend import determinism; "
                        "print(determinism.enabled())"], capture_output=True, text=True,
                       check=True, env=os.environ.copy())
  assert out.stdout.strip() == "True"
  determinism.require()  # already on: nothing to do, no error once jax has started


def test_the_deterministic_flag_is_set_before_the_cli_starts_jax(tmp_path):
  """nerf-train's set-up asks jax for the process index, which starts its backends: on a GPU the
  flag set after that was refused (train.deterministic failed on an H200). So the flag must be in
  XLA_FLAGS when the first backend starts; a spy on jax's backend start records XLA_FLAGS then."""
  script = (
      "import os\n"
      "from jax._src import xla_bridge\n"
      "seen, start = [], xla_bridge.backends\n"
      "def spy():\n"
      "  seen.append(os.environ.get('XLA_FLAGS', ''))\n"
      "  return start()\n"
      "xla_bridge.backends = spy\n"
      "from nerf_jax import cli\n"
      "from nerf_jax.run import config_lib\n"
      "config = config_lib.load('default')\n"
      "config.train.deterministic = True\n"
      f"cli.prepare(config, {str(tmp_path)!r})\n"
      "print(repr(seen[0]))\n")
  env = {k: v for k, v in os.environ.items() if k != "XLA_FLAGS"}
  out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, env=env,
                       cwd=os.path.dirname(os.path.dirname(os.path.dirname(__file__))))
  assert out.returncode == 0, out.stderr[-2000:]
  assert determinism.FLAG in out.stdout.splitlines()[-1]
