"""The per-ray pipeline and chunked image rendering."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.configs import debug
from nerf_jax import field, image_renderer, renderer
from nerf_jax.model import make_model
from nerf_jax.rays import Rays, get_rays, pose_spherical


def _setup(**overrides):
  config = debug.get_config()
  for key, value in overrides.items():
    node = config
    *path, last = key.split(".")
    for p in path:
      node = node[p]
    node[last] = value
  model = make_model(config.model)
  params = field.init_params(model, config, jax.random.PRNGKey(0))
  return config, model, params


def _rays(n=37):
  origins, directions = get_rays(9, 10, 8.0, pose_spherical(20.0, -30.0, 4.0))
  return origins.reshape(-1, 3)[:n], directions.reshape(-1, 3)[:n]


@pytest.mark.parametrize("fine", [0, 8])
def test_render_image_in_chunks_equals_one_call(fine):
  config, model, params = _setup(num_fine_samples=fine)
  origins, directions = _rays()
  rays = Rays.create(origins, directions, 2.0, 6.0)
  whole = renderer.final(renderer.render_rays(model, params, rays, config))
  chunked = image_renderer.render_image(image_renderer.make_chunk_renderer(model, config), params,
                                        rays, chunk=16)
  for k in ("rgb", "depth", "acc"):
    np.testing.assert_allclose(chunked[k], whole[k], rtol=1e-5, atol=1e-6)


def test_render_image_does_not_recompile_across_images():
  config, model, params = _setup()
  render_chunk = image_renderer.make_chunk_renderer(model, config)
  for n in (37, 20, 64):
    origins, directions = _rays(n)
    out = image_renderer.render_image(render_chunk, params,
                                      Rays.create(origins, directions, 2.0, 6.0), chunk=16)
    assert out["rgb"].shape == (n, 3)
  assert render_chunk._cache_size() == 1


def test_hierarchical_pass_uses_union_of_edges():
  config, model, params = _setup(num_fine_samples=8)
  origins, directions = _rays(5)
  out = renderer.render_rays(model, params, Rays.create(origins, directions, 2.0, 6.0), config,
                             key=jax.random.PRNGKey(1))
  t_coarse, t_fine = out["coarse"]["t"], out["fine"]["t"]
  assert t_fine.shape == (5, config.num_samples + 8 + 1)
  assert np.all(np.diff(t_fine, axis=-1) >= 0)
  for row_c, row_f in zip(np.asarray(t_coarse), np.asarray(t_fine)):
    assert np.all(np.isin(row_c, row_f))  # every coarse edge is kept
  assert set(params) == {"coarse", "fine"}


def test_shared_fine_network_has_one_parameter_set():
  config, _, params = _setup(num_fine_samples=8, **{"model.shared_fine": True})
  assert set(params) == {"coarse"}


def test_deterministic_without_key_and_random_with_key():
  config, model, params = _setup()
  rays = Rays.create(*_rays(9), 2.0, 6.0)
  render = lambda key: renderer.final(renderer.render_rays(model, params, rays, config,
                                                           key=key))["rgb"]
  np.testing.assert_array_equal(render(None), render(None))
  np.testing.assert_array_equal(render(jax.random.PRNGKey(3)), render(jax.random.PRNGKey(3)))
  assert np.max(np.abs(render(jax.random.PRNGKey(3)) - render(jax.random.PRNGKey(4)))) > 0


def test_density_noise_only_with_a_key():
  config, model, params = _setup(**{"model.density_noise": 1.0})
  rays = Rays.create(*_rays(9), 2.0, 6.0)
  t = jnp.broadcast_to(jnp.linspace(2.0, 6.0, 5), (9, 5))
  points = rays.origins[:, None] + rays.directions[:, None] * t[..., None]
  _, s0 = field.query(model, params["coarse"], points, rays.viewdirs, config)
  _, s1 = field.query(model, params["coarse"], points, rays.viewdirs, config)
  _, s2 = field.query(model, params["coarse"], points, rays.viewdirs, config,
                               key=jax.random.PRNGKey(0))
  np.testing.assert_array_equal(s0, s1)
  assert np.all(s2 >= 0) and np.max(np.abs(s2 - s0)) > 0


@pytest.mark.parametrize("view_dependent", [False, True])
def test_remat_chunks_match_one_call_in_values_and_gradients(view_dependent):
  config, model, params = _setup(**{"model.view_dependent": view_dependent})
  origins, directions = _rays(36)
  rays = Rays.create(origins, directions, 2.0, 6.0)
  key = jax.random.PRNGKey(3)

  def loss(p, chunk):
    config.train.remat_chunk = chunk
    out = renderer.render_rays(model, p, rays, config, key=key)["coarse"]
    return jnp.sum(out["rgb"] ** 2) + jnp.sum(out["depth"]), out["rgb"]

  (plain, rgb_plain), g_plain = jax.value_and_grad(loss, has_aux=True)(params, 0)
  (chunked, rgb_chunked), g_chunked = jax.value_and_grad(loss, has_aux=True)(params, 12)
  np.testing.assert_allclose(rgb_chunked, rgb_plain, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(chunked, plain, rtol=1e-5)
  for a, b in zip(jax.tree_util.tree_leaves(g_chunked), jax.tree_util.tree_leaves(g_plain)):
    np.testing.assert_allclose(a, b, rtol=1e-4, atol=1e-6)
  # A chunk size that does not divide the batch falls back to one call.
  config.train.remat_chunk = 10
  odd = renderer.render_rays(model, params, rays, config, key=key)["coarse"]["rgb"]
  np.testing.assert_array_equal(odd, rgb_plain)
