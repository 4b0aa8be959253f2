"""Marching (render-time empty-space skipping + early ray termination) against the plain path.

Analytic fields check the pieces; a trained fast model checks the whole renderer: the marching
image equals the plain one within the documented bounds while querying a fraction of the samples.
"""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax import rendering
from nerf_jax.render import background, empty_space, image_renderer
from nerf_jax.run import builders, experiment
from nerf_jax.samplers import spacing
from nerf_jax.run import train_lib
from tests.helpers import assert_beats_trivial
from tests.helpers import ray_renderer, small_config

NUM_RAYS, NUM_SAMPLES = 64, 32
RADIUS = 0.5  # the analytic field: a ball of this radius at the origin


def _ball_field(density):
  """field_fn of a ball of constant density (colour = position-dependent), empty outside."""
  def field(params, points, viewdirs):
    del params, viewdirs
    inside = jnp.sum(points ** 2, axis=-1) < RADIUS ** 2
    rgb = jax.nn.sigmoid(points * 3.0)
    return rgb, jnp.where(inside, density, 0.0)
  return field


def _rays():
  """Parallel rays along -z through a 8×8 grid of x, y in [-0.7, 0.7] (some miss the ball)."""
  xy = np.stack(np.meshgrid(np.linspace(-0.7, 0.7, 8), np.linspace(-0.7, 0.7, 8)), -1)
  origins = np.concatenate([xy.reshape(-1, 2), np.full((NUM_RAYS, 1), 2.0)], -1)
  directions = np.tile([0.0, 0.0, -1.0], (NUM_RAYS, 1))
  t = spacing.stratified(1.0, 3.0, NUM_SAMPLES, (NUM_RAYS,))
  points = origins[:, None, :] + directions[:, None, :] * spacing.midpoints(t)[..., None]
  return (jnp.asarray(t), jnp.asarray(points, jnp.float32),
          jnp.asarray(directions, jnp.float32))


def _plain_and_marched(density, mask, min_transmittance, live=None, group=4):
  field = _ball_field(density)
  t, points, viewdirs = _rays()
  rgb_all, sigma_all = field(None, points.reshape(-1, 3), None)
  plain = rendering.composite(rgb_all.reshape(NUM_RAYS, NUM_SAMPLES, 3),
                              sigma_all.reshape(NUM_RAYS, NUM_SAMPLES), t)
  occupied, rank = empty_space.occupied_ranks(mask, points, 1.0)
  live = np.ones(NUM_RAYS, bool) if live is None else live
  sigma, rgb, queried = empty_space.march(empty_space.make_query_round(field), None, t, points,
                                       viewdirs, occupied, rank, live, group, min_transmittance)
  return plain, rendering.composite(rgb, sigma, t), queried, occupied


def test_marching_everything_is_exactly_the_plain_composite():
  # Every cell occupied, no termination: every sample is queried and nothing changes.
  mask = jnp.ones((8, 8, 8), bool)
  plain, marched, queried, _ = _plain_and_marched(5.0, mask, 0.0)
  assert queried >= NUM_RAYS * NUM_SAMPLES
  for k in ("rgb", "acc", "depth"):
    np.testing.assert_allclose(marched[k], plain[k], rtol=1e-6, atol=1e-6)


def test_early_termination_error_is_below_min_transmittance():
  mask = jnp.ones((8, 8, 8), bool)
  min_t, group = 1e-3, 4
  plain, marched, queried, _ = _plain_and_marched(200.0, mask, min_t, group=group)
  assert np.max(np.abs(marched["rgb"] - plain["rgb"])) <= min_t
  assert np.max(np.abs(marched["acc"] - plain["acc"])) <= min_t
  # One sample inside the ball (σ·δ = 200·2/32 = 12.5) leaves transmittance e^-12.5 < 1e-3, so a
  # ray that hits the ball stops after the round holding its first sample inside; a ray that
  # misses queries all of its samples.
  _, points, _ = _rays()
  inside = np.sum(np.asarray(points) ** 2, axis=-1) < RADIUS ** 2
  first = np.argmax(inside, axis=-1)
  expected = np.where(inside.any(-1), (first // group + 1) * group, NUM_SAMPLES)
  assert inside.any(-1).sum() >= 8
  assert queried == expected.sum()


def test_skipped_cells_are_never_queried_and_exact_where_empty():
  # A mask of the ball's cells (grid over [-1, 1]^3): outside samples are skipped, and they are
  # empty, so the image is exactly the plain one.
  field = _ball_field(5.0)
  mask = empty_space.skip_grid(lambda p: field(None, p, None)[1], 16, 1.0, 1e-3, 2)
  plain, marched, queried, occupied = _plain_and_marched(5.0, mask, 0.0)
  assert 0 < int(occupied.sum()) < 0.5 * occupied.size
  assert queried < 0.5 * NUM_RAYS * NUM_SAMPLES
  np.testing.assert_allclose(marched["rgb"], plain["rgb"], atol=1e-6)


def test_an_empty_mask_or_dead_rays_query_nothing():
  _, marched, queried, _ = _plain_and_marched(5.0, jnp.zeros((8, 8, 8), bool), 0.0)
  assert queried == 0 and np.all(marched["acc"] == 0)
  _, _, queried, _ = _plain_and_marched(5.0, jnp.ones((8, 8, 8), bool), 0.0,
                                        live=np.zeros(NUM_RAYS, bool))
  assert queried == 0


def test_buffers_cover_every_selected_sample_once():
  small, large = empty_space.SMALL_BUFFER, empty_space.LARGE_BUFFER
  assert empty_space.buffers(0) == []
  assert empty_space.buffers(1) == [(0, small)]
  assert empty_space.buffers(small + 1) == [(0, 2 * small)]
  assert empty_space.buffers(2 * large + 1) == [(0, large), (large, large), (2 * large, small)]


@pytest.mark.parametrize("small,large", [(16, 128), (16, 100)])
def test_buffer_sizes_are_every_size_buffers_uses(monkeypatch, small, large):
  monkeypatch.setattr(empty_space, "SMALL_BUFFER", small)
  monkeypatch.setattr(empty_space, "LARGE_BUFFER", large)
  for max_count in (1, 16, 17, 100, 128, 129, 500):
    used = {size for count in range(max_count + 1) for _, size in empty_space.buffers(count)}
    assert empty_space.buffer_sizes(max_count) == sorted(used)


def test_a_round_bigger_than_a_buffer_is_queried_in_several(monkeypatch):
  monkeypatch.setattr(empty_space, "SMALL_BUFFER", 16)
  monkeypatch.setattr(empty_space, "LARGE_BUFFER", 100)  # a round of 64 rays needs several
  plain, marched, queried, _ = _plain_and_marched(5.0, jnp.ones((8, 8, 8), bool), 0.0)
  assert queried == NUM_RAYS * NUM_SAMPLES
  np.testing.assert_allclose(marched["rgb"], plain["rgb"], rtol=1e-6, atol=1e-6)


@pytest.mark.parametrize("change", [{"num_fine_samples": 8}, {"data.scene_bound": 0.0},
                                    {"render.march": False}, {"occupancy.enabled": True}])
def test_marching_only_where_it_applies(change):
  marches = lambda config: image_renderer.marches(ray_renderer(config),
                                                  builders.image_settings(config))
  assert marches(small_config(base="fast"))
  assert not marches(small_config(change, base="fast"))


@pytest.fixture(scope="module")
def trained_fast(tmp_path_factory):
  """A fast-config model trained briefly on a small diffuse scene: (experiment, variables)."""
  config = small_config({"data.num_views": 24, "data.image_size": 32, "data.holdout_from": 20,
                         "model.grid.resolutions": (16, 32), "num_samples": 48,
                         "train.batch_rays": 1024, "train.max_steps": 200, "train.log_every": 100,
                         "train.checkpoint_every": 200, "render.chunk": 512,
                         "render.march_grid": 48}, base="fast")  # the shipped skip grid
  workdir = str(tmp_path_factory.mktemp("fast") / "run")
  result = train_lib.train_and_evaluate(config, workdir)
  exp, state = experiment.restore(workdir)
  assert_beats_trivial(result["psnr"], exp)  # the model has learnt the scene: empty is empty
  return exp, state.variables


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_marching_renders_the_plain_image_of_a_trained_model(trained_fast):
  exp, variables = trained_fast
  config, test_ds = exp.config, exp.test_ds
  assert image_renderer.marches(exp.renderer, exp.image)
  bg = background.parse(config.data.background)
  marched = image_renderer.make_image_renderer(exp.renderer, exp.image)(variables)
  plain_chunk = image_renderer.make_chunk_renderer(exp.renderer)
  for i in range(len(test_ds)):
    rays = exp.rays(test_ds.poses[i])
    a = image_renderer.render_image(plain_chunk, variables, rays, bg, config.render.chunk)
    b = marched(rays, bg)
    assert np.max(np.abs(a["rgb"] - b["rgb"])) < 2e-2
    assert np.mean(np.abs(a["rgb"] - b["rgb"])) < 2e-3
    # The documented bound on opacity: the skipped cells' density along the longest segment in
    # the box (its diagonal), plus the light left behind a terminated ray.
    rc = config.render
    bound = 1.0 - np.exp(-rc.march_threshold * 2.0 * np.sqrt(3.0) * config.data.scene_bound)
    assert np.max(np.abs(a["acc"] - b["acc"])) <= bound + rc.min_transmittance
    solid = (a["acc"] > 0.9) & (b["acc"] > 0.9)
    assert np.max(np.abs(a["depth"] - b["depth"])[solid]) < 0.05


def test_marching_skips_most_samples_of_a_trained_model(trained_fast):
  exp, variables = trained_fast
  config, params = exp.config, variables["params"]
  marcher = image_renderer._Marcher(exp.renderer, exp.image)  # pylint: disable=protected-access
  mask = marcher.skip_grid(params)
  rays = exp.rays(exp.test_ds.poses[0]).reshape(-1)
  _, t_world, points, occupied, rank, _ = marcher.plan(mask, None, rays)
  _, _, queried = empty_space.march(marcher.query_round, params, t_world, points, rays.viewdirs,
                                 occupied, rank, np.ones(t_world.shape[0], bool),
                                 config.render.march_group, config.render.min_transmittance)
  assert 0.0 < float(jnp.mean(mask)) < 0.5  # the trained toy field: about 12% non-empty
  assert queried < 0.4 * occupied.size


def test_marching_with_a_visual_hull_renders_the_plain_image_with_it(trained_fast):
  # Half the box ruled out (x > 0): the marcher leaves those samples out as the plain path
  # gives them no density, and both agree within the documented skip bound above.
  exp, variables = trained_fast
  config = exp.config
  hull = np.ones((16, 16, 16), np.float32)
  hull[8:] = 0.0
  gated = {**variables, "hull": jnp.asarray(hull)}
  bg = background.parse(config.data.background)
  rays = exp.rays(exp.test_ds.poses[0])
  plain_chunk = image_renderer.make_chunk_renderer(exp.renderer)
  a = image_renderer.render_image(plain_chunk, gated, rays, bg, config.render.chunk)
  b = image_renderer.make_image_renderer(exp.renderer, exp.image)(gated)(rays, bg)
  whole = image_renderer.render_image(plain_chunk, variables, rays, bg, config.render.chunk)
  assert np.mean(np.abs(a["acc"] - whole["acc"])) > 1e-2  # the hull removed something
  rc = config.render
  bound = 1.0 - np.exp(-rc.march_threshold * 2.0 * np.sqrt(3.0) * config.data.scene_bound)
  assert np.max(np.abs(a["acc"] - b["acc"])) <= bound + rc.min_transmittance
  assert np.mean(np.abs(a["rgb"] - b["rgb"])) < 2e-3
