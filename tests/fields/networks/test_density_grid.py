"""Density from a grid of its own, and colour only where the weights say it matters: each half of
the split network equals the whole; a full colour budget renders exactly what the plain pass
renders; a partial one errs by no more than the weight it leaves out (a closed-form bound)."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields.networks import density_grid
from nerf_jax.fields.encodings import grid
from nerf_jax.fields.protocol import NetworkSettings
from nerf_jax.render import renderer
from nerf_jax.run import builders
from nerf_jax.run.signature import model_signature
from tests.helpers import SPLIT_GRID, ball_in_first_density_level, jitted, small_config
from tests.helpers import small_view_rays

def _split_network(view_dependent=False, **settings):
  """A DensityGridNeRF over the grid encoding of `settings` (grid.Settings) on the 1.5 cube."""
  encoding = grid.DenseGrid(grid.Settings(**settings), grid.Space(1.5))
  return density_grid.DensityGridNeRF(encoding, NetworkSettings(view_dependent=view_dependent))


def test_each_half_of_the_split_network_equals_the_whole():
  net = _split_network(True, resolutions=(4, 8), features=2, density_resolutions=(8,))
  points = jax.random.uniform(jax.random.PRNGKey(0), (50, 3), minval=-1.6, maxval=1.6)
  dirs = jax.random.normal(jax.random.PRNGKey(1), (50, 27))
  variables = net.init(jax.random.PRNGKey(2), points, dirs)
  rgb, raw = net.apply(variables, points, dirs)
  np.testing.assert_array_equal(net.apply(variables, points, part="density"), raw)
  np.testing.assert_array_equal(net.apply(variables, points, dirs, part="colour"), rgb)
  unit = grid.to_unit_cube(points, 1.5)
  inside = np.asarray(grid.inside_box(unit))
  np.testing.assert_allclose(np.asarray(raw)[inside], density_grid.INITIAL_RAW_DENSITY, rtol=1e-6)
  assert np.all(np.asarray(raw)[~inside] == -1e5)  # a nearly empty start, empty outside
  density = jax.random.normal(jax.random.PRNGKey(4), variables["params"]["density_8"].shape)
  variables["params"]["density_8"] = density
  raw = net.apply(variables, points, part="density")
  np.testing.assert_allclose(np.asarray(raw)[inside], density_grid.DENSITY_GAIN * np.asarray(
      grid.trilinear(density, unit)[..., 0])[inside], rtol=1e-5, atol=1e-5)


def _renderers(fraction, occupied=False):
  config = small_config(SPLIT_GRID, base="fast", **{"model.colour_fraction": fraction,
                                                "occupancy.enabled": occupied})
  split = builders.make_ray_renderer(config)
  return split, renderer.RayRenderer(split.field, split.sampler)


def _split_and_plain(fraction, occupied):
  """The coarse pass of the split and the plain renderer on the same ball-shaped field."""
  split, plain = _renderers(fraction, occupied)
  variables = jitted(split.init)(jax.random.PRNGKey(0))
  variables["params"]["coarse"] = ball_in_first_density_level(variables["params"]["coarse"])
  rays = small_view_rays()
  return (jitted(split.render)(variables, rays)["coarse"],
          jitted(plain.render)(variables, rays)["coarse"])


@pytest.mark.parametrize("occupied", [False, True])
def test_a_full_colour_budget_renders_what_the_plain_pass_renders(occupied):
  a, b = _split_and_plain(1.0, occupied)
  for name in ("rgb", "acc", "depth", "weights"):
    np.testing.assert_allclose(a[name], b[name], atol=2e-6, err_msg=name)


@pytest.mark.parametrize("occupied", [False, True])
def test_a_partial_budget_errs_by_at_most_the_weight_it_leaves_out(occupied):
  got, want = _split_and_plain(0.25, occupied)
  weights = np.asarray(want["weights"])  # identical densities: identical weights
  np.testing.assert_allclose(got["weights"], weights, atol=1e-6)
  if occupied:  # interval 2k is sample k, 2k + 1 the empty gap after it
    weights = weights[..., ::2]
  k = int(np.ceil(0.25 * weights.size))
  threshold = np.sort(weights.reshape(-1))[-k]
  left_out = np.where(weights >= threshold, 0.0, weights).sum(-1)  # colours lie in (0, 1)
  error = np.abs(np.asarray(got["rgb"]) - np.asarray(want["rgb"])).max(-1)
  assert np.all(error <= left_out + 1e-5)
  assert left_out.max() < 0.05 and weights.sum(-1).max() > 0.5  # the test has teeth


def test_split_gradients_are_finite_and_reach_both_halves():
  split, _ = _renderers(0.25)
  variables = jitted(split.init)(jax.random.PRNGKey(0))
  rays = small_view_rays()

  def loss(params):
    out = split.render({"params": params}, rays, jax.random.PRNGKey(3))["coarse"]
    return jnp.mean((out["rgb"] - 0.5) ** 2)

  grads = jitted(jax.grad(loss))(variables["params"])["coarse"]
  assert all(bool(jnp.all(jnp.isfinite(g))) for g in jax.tree_util.tree_leaves(grads))
  assert float(jnp.abs(grads["density_16"]).sum()) > 0
  assert float(jnp.abs(grads["grid_16"]).sum()) > 0


def test_density_grid_with_relu_is_refused():
  config = small_config(SPLIT_GRID, base="fast", **{"model.density_activation": "relu"})
  with pytest.raises(ValueError, match="density_activation"):
    builders.make_field(config)


def test_occupancy_probes_read_the_density_half():
  split, _ = _renderers(0.25)
  params = ball_in_first_density_level(jitted(split.init)(jax.random.PRNGKey(0))["params"]["coarse"])
  points = jnp.array([[0.0, 0.0, 0.0], [1.2, 1.2, 1.2]])
  sigma = jitted(lambda p, x: split.field.density(p)(x))(params, points)
  _, full = jitted(split.field.query)(params, points[:, None, :], jnp.zeros((2, 3)))
  np.testing.assert_allclose(sigma, full[:, 0], rtol=1e-6)
  assert float(sigma[0]) > 3.0 and float(sigma[1]) < 0.01


def _hashed_brute(table, point, resolution, log2_size):
  """Trilinear interpolation of a hashed level at one unit-cube point, corner by corner, with
  instant-ngp's hash written out in Python integers."""
  x = np.clip(point, 0.0, 1.0) * (resolution - 1)
  lower = np.minimum(np.floor(x), resolution - 2).astype(np.int64)
  frac = x - lower
  total = 0.0
  for corner in np.ndindex(2, 2, 2):
    c = lower + np.array(corner)
    row = ((int(c[0]) * 1) ^ (int(c[1]) * 2654435761) ^ (int(c[2]) * 805459861)) % 2 ** 32
    row %= 2 ** log2_size
    weight = np.prod(np.where(np.array(corner) == 1, frac, 1.0 - frac))
    total += weight * table[row, 0]
  return total


def _hashed_network(part):
  """(network, points float32 [40, 3], variables): a split network whose `part` ('density' or
  'colour') has a hashed level of 32^3 points in 2^8 rows, and random points in its box."""
  net = _split_network(resolutions=(4,), features=2, density_resolutions=(8,),
                       **{f"{part}_hash_resolution": 32, f"{part}_hash_log2_size": 8})
  points = jax.random.uniform(jax.random.PRNGKey(0), (40, 3), minval=-1.4, maxval=1.4)
  return net, points, net.init(jax.random.PRNGKey(2), points, jnp.zeros((40, 3)))


def test_a_hashed_density_level_adds_its_hash_lookup_to_the_dense_levels():
  net, points, variables = _hashed_network("density")
  params = variables["params"]
  assert params["hashed_density"].shape == (256, 1)  # 32^3 points share 2^8 rows
  unit = grid.to_unit_cube(points, 1.5)
  density = jitted(net.apply, part="density")
  np.testing.assert_allclose(density(variables, points),
                             density_grid.INITIAL_RAW_DENSITY, rtol=1e-6)  # the same faint start
  params["density_8"] = jax.random.normal(jax.random.PRNGKey(3), params["density_8"].shape)
  params["hashed_density"] = jax.random.normal(jax.random.PRNGKey(4), (256, 1))
  raw = np.asarray(net.apply(variables, points, part="density"))  # op by op: the summation
  # order of the reference, where one compiled program differs by up to ~4e-5 (terms up to ~20
  # cancelling to values near 0)
  dense = np.asarray(grid.trilinear(params["density_8"], unit)[..., 0])
  hashed = [_hashed_brute(np.asarray(params["hashed_density"]), u, 32, 8)
            for u in np.asarray(unit)]
  np.testing.assert_allclose(raw, density_grid.DENSITY_GAIN * (dense + np.array(hashed)),
                             rtol=1e-5, atol=1e-5)
  # Its gradient reaches only the rows the points' corners hash to.
  grad = jitted(jax.grad(lambda p: jnp.sum(density({"params": p}, points))))(params)
  touched = np.flatnonzero(np.asarray(grad["hashed_density"])[:, 0])
  assert 0 < len(touched) <= 8 * len(points)


def test_a_hashed_colour_level_joins_the_colour_features():
  net, points, variables = _hashed_network("colour")
  params = variables["params"]
  assert params["hashed_colour"].shape == (256, 2)
  assert params["hidden"]["kernel"].shape[0] == 2 + 2  # the dense level's and the hashed one's
  # The colour's gradient reaches the hashed rows; density does not read them.
  colour = lambda p: jnp.sum(net.apply({"params": p}, points, part="colour"))
  assert np.any(np.asarray(jitted(jax.grad(colour))(params)["hashed_colour"]) != 0)
  density = jitted(net.apply, part="density")
  raw = density(variables, points)
  params["hashed_colour"] = params["hashed_colour"] + 1.0
  np.testing.assert_array_equal(density(variables, points), raw)


@pytest.mark.parametrize("part", ["density", "colour"])
def test_a_hashed_level_needs_the_dense_density_levels(part):
  config = small_config({f"model.grid.{part}_hash_resolution": 32}, base="fast")
  with pytest.raises(ValueError, match="density_resolutions"):
    builders.make_ray_renderer(config)
  config = small_config({**SPLIT_GRID, f"model.grid.{part}_hash_resolution": 32}, base="fast")
  assert model_signature(config)[f"grid_{part}_hash"] == [32, 20]
  variables = jitted(builders.make_ray_renderer(config).init)(jax.random.PRNGKey(0))
  table = variables["params"]["coarse"][f"hashed_{part}"]
  assert table.shape[0] == 2 ** 15  # 32^3 points fit 2^20 rows: indexed densely, as grid.py


def _antialiased_network(multisample):
  """The split network with Zip-NeRF's antialias on (levels 4 and 8 a side on the 1.5 cube)."""
  return _split_network(True, resolutions=(4, 8), features=2, density_resolutions=(4, 8),
                        antialias=True, multisample=multisample)


def _random_levels(net, points, dirs):
  variables = net.init(jax.random.PRNGKey(2), points, dirs)
  params = dict(variables["params"])
  for i, name in enumerate(("density_4", "density_8")):
    params[name] = jax.random.normal(jax.random.PRNGKey(10 + i), params[name].shape)
  return {"params": params}


def test_antialiased_density_weighs_each_level_by_its_cells_against_the_scale():
  net = _antialiased_network(False)
  points = jax.random.uniform(jax.random.PRNGKey(0), (4, 3), minval=-1.0, maxval=1.0)
  dirs = jax.random.normal(jax.random.PRNGKey(1), (4, 27))
  variables = _random_levels(net, points, dirs)
  std = np.array([0.0, 0.05, 0.3, np.inf], np.float32)
  raw = net.apply(variables, points, part="density",
                  multisamples=(points[:, None], jnp.asarray(std)[:, None]))
  unit = grid.to_unit_cube(points, 1.5)
  want = 0.0
  for r in (4, 8):
    cell = 3.0 / (r - 1)  # the cube's side over its cells
    weight = np.array([1.0 if s == 0 else math.erf(cell / (math.sqrt(8.0) * s)) for s in std])
    level = np.asarray(grid.trilinear(variables["params"][f"density_{r}"], unit)[..., 0])
    want = want + weight * level
  np.testing.assert_allclose(raw, density_grid.DENSITY_GAIN * want, rtol=1e-5, atol=1e-5)
  assert raw[3] == 0.0 and abs(float(raw[0] - raw[2])) > 0.1  # the test has teeth
  point = net.apply(variables, points, part="density")
  np.testing.assert_array_equal(raw[0], point[0])  # scale 0: the point's density


def test_antialiased_frustum_averages_its_six_points_and_fades_to_the_featureless_colour():
  net = _antialiased_network(True)
  apply = jax.jit(net.apply, static_argnames="part")
  points = jax.random.uniform(jax.random.PRNGKey(0), (5, 3), minval=-1.0, maxval=1.0)
  dirs = jax.random.normal(jax.random.PRNGKey(1), (5, 27))
  variables = _random_levels(net, points, dirs)
  six = points[:, None] + 0.1 * jax.random.normal(jax.random.PRNGKey(3), (5, 6, 3))
  raw = apply(variables, points, part="density", multisamples=(six, jnp.zeros((5, 6))))
  each = jnp.stack([apply(variables, six[:, i], part="density") for i in range(6)], -1)
  np.testing.assert_allclose(raw, each.mean(-1), rtol=1e-5, atol=1e-5)
  wide = (six, jnp.full((5, 6), jnp.inf))
  rgb = apply(variables, points, dirs, part="colour", multisamples=wide)
  featureless = jax.tree_util.tree_map(jnp.zeros_like, variables)
  featureless["params"] = {**variables["params"], **{
      k: jnp.zeros_like(v) for k, v in variables["params"].items() if k.startswith("grid_")}}
  np.testing.assert_allclose(rgb, apply(featureless, points, dirs, part="colour"),
                             rtol=1e-6, atol=1e-7)
  assert np.all(np.asarray(apply(variables, points, part="density", multisamples=wide)) == 0)


@pytest.mark.parametrize("multisample", [False, True])
def test_cones_render_alike_through_the_colour_share_and_the_sample_budget(multisample):
  config = small_config(SPLIT_GRID, base="fast", **{
      "model.colour_fraction": 1.0, "model.grid.antialias": True,
      "model.grid.multisample": multisample, "occupancy.enabled": True,
      "occupancy.resolution": 16})
  split = builders.make_ray_renderer(config)
  plain = renderer.RayRenderer(split.field, split.sampler)  # every sample's colour, no budget
  variables = jitted(split.init)(jax.random.PRNGKey(0))
  variables["params"]["coarse"] = ball_in_first_density_level(variables["params"]["coarse"])
  variables["occupancy"] = jitted(split.occupancy_grid)(variables)
  rays = small_view_rays()
  # Footprints ~0.4 wide at the ball: the weight of its level (cells of 3/7) drops to ~0.4.
  rays = rays.replace(radii=jnp.full(rays.near.shape, 0.1))
  valid = np.asarray(jitted(split.sampler.place)(rays, None, variables["occupancy"]).valid)
  want = jitted(plain.render)(variables, rays)["coarse"]
  for budget in (int(valid.sum()), int(valid.sum()) // 2):
    got = jitted(dataclasses.replace(split, sample_budget=budget).render)(variables, rays)
    complete = np.asarray(got["coarse"]["complete"])
    np.testing.assert_array_equal(complete, np.cumsum(valid.sum(-1)) <= budget)
    for name in ("rgb", "acc"):
      np.testing.assert_allclose(np.asarray(got["coarse"][name])[complete],
                                 np.asarray(want[name])[complete], atol=2e-6, err_msg=name)
  points = renderer.RayRenderer(builders.make_ray_renderer(small_config(SPLIT_GRID, base="fast", **{
      "occupancy.enabled": True, "occupancy.resolution": 16})).field, split.sampler)
  as_points = jitted(points.render)(variables, rays)["coarse"]
  assert float(jnp.abs(as_points["acc"] - want["acc"]).max()) > 0.01  # the cones are read
  assert float(want["acc"].max()) > 0.3  # rays cross the ball


def test_appearance_codes_change_colour_alone_and_read_each_points_image():
  """Each point's code is row `image` of the table, joined after the hidden layer as the lattice
  head's; density never sees it; image None is the table's mean row."""
  net = density_grid.DensityGridNeRF(
      grid.DenseGrid(grid.Settings(resolutions=(4, 8), features=2, density_resolutions=(8,)),
                     grid.Space(1.5)),
      NetworkSettings(view_dependent=True, appearance_dims=3, appearance_images=5))
  points = jax.random.uniform(jax.random.PRNGKey(0), (6, 4, 3), minval=-1.4, maxval=1.4)
  dirs = jax.random.normal(jax.random.PRNGKey(1), (6, 4, 27))
  rays_image = jnp.array([0, 1, 2, 3, 4, 1])
  variables = net.init(jax.random.PRNGKey(2), points, dirs, rays_image)
  table = jax.random.normal(jax.random.PRNGKey(3), (5, 3))
  variables["params"]["appearance"] = table
  rgb, raw = net.apply(variables, points, dirs, rays_image)
  # Each point alone with its ray's image ([P] images for [P, 3] points): the same colours.
  flat_image = jnp.repeat(rays_image, 4)
  colour = net.apply(variables, points.reshape(-1, 3), dirs.reshape(-1, 27), flat_image,
                     part="colour")
  np.testing.assert_allclose(colour, rgb.reshape(-1, 3), rtol=1e-6, atol=1e-7)
  # A brute-force reference: the image's row given as the table's only row (image 0 of 1).
  for ray in (0, 3):
    alone = dict(variables["params"], appearance=table[rays_image[ray]][None])
    single = dataclasses.replace(net, shared=dataclasses.replace(net.shared, appearance_images=1))
    want = single.apply({"params": alone}, points[ray], dirs[ray], jnp.zeros(4, jnp.int32),
                        part="colour")
    np.testing.assert_allclose(rgb[ray], want, rtol=1e-6, atol=1e-7)
  mean = dict(variables["params"], appearance=jnp.mean(table, 0, keepdims=True))
  np.testing.assert_allclose(
      net.apply(variables, points[0], dirs[0], None, part="colour"),
      single.apply({"params": mean}, points[0], dirs[0], jnp.zeros(4, jnp.int32), part="colour"),
      rtol=1e-6, atol=1e-7)
  # Density ignores the code; colour does not (teeth).
  np.testing.assert_array_equal(net.apply(variables, points, dirs, rays_image[::-1])[1], raw)
  assert float(jnp.abs(net.apply(variables, points, dirs, rays_image[::-1])[0] - rgb).max()) > 1e-3


def test_appearance_codes_render_alike_through_the_colour_share_and_the_plain_pass():
  config = small_config(SPLIT_GRID, base="fast", **{
      "model.colour_fraction": 1.0, "model.appearance_dims": 4})
  split = builders.make_ray_renderer(config, num_images=3)
  plain = renderer.RayRenderer(split.field, split.sampler)  # every sample's colour
  variables = jitted(split.init)(jax.random.PRNGKey(0))
  variables["params"]["coarse"] = ball_in_first_density_level(variables["params"]["coarse"])
  table = variables["params"]["coarse"]["appearance"]
  variables["params"]["coarse"]["appearance"] = jax.random.normal(jax.random.PRNGKey(5),
                                                                  table.shape)
  rays = small_view_rays()
  rays = rays.replace(image=jnp.arange(rays.near.shape[0], dtype=jnp.int32) % 3)
  want = jitted(plain.render)(variables, rays)["coarse"]
  got = jitted(split.render)(variables, rays)["coarse"]
  for name in ("rgb", "acc"):
    np.testing.assert_allclose(got[name], want[name], atol=2e-6, err_msg=name)
  other = jitted(split.render)(variables, rays.replace(image=(rays.image + 1) % 3))["coarse"]
  assert float(jnp.abs(other["rgb"] - got["rgb"]).max()) > 1e-3  # the codes are read
