"""Cones through the field and the renderer (model.encoding 'ipe', configs/mipnerf.py): the
Field's Gaussians against mip-NeRF's frustum moments written here in float64 (the expanded
quotients), the integrated encoding with variance 0 against the point encoding, bit for bit,
and the renderer against a pass written out by hand. jax_debug_nans is on: a NaN anywhere, a
backward pass included, fails the test.
"""

import dataclasses
import itertools
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import cones
from nerf_jax.cameras.rays import Rays
from nerf_jax.render import compositing, image_renderer, renderer as renderer_lib
from nerf_jax.fields.encodings import grid
from nerf_jax.run import builders
from nerf_jax.samplers import placement
from tests.helpers import small_config, sphere_rays

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: NaNs raise in this module

SMALL = {"num_samples": 8, "num_fine_samples": 8, "pos_encode_dims": 6, "model.width": 16,
         "model.depth": 2, "model.skip_layers": ()}


def _field(**overrides):
  return builders.make_field(small_config({**SMALL, **overrides}, base="mipnerf"))


def _rays(num=6, radius=0.01, near=2.0, far=6.0, seed=0):
  origins, directions = sphere_rays(num, seed, unit=False)
  rays = Rays.create(origins, directions, near, far)
  return rays.replace(radii=jnp.full(rays.shape, radius, jnp.float32))


def _frustum_reference(o, d, radius, t0, t1, full=False):
  """float64 (mean [..., S, 3], diagonal variance [..., S, 3], or with `full` the covariance
  [..., S, 3, 3] t_var·d dᵀ + r_var·(I - d dᵀ/|d|^2)) of each frustum, from the
  expanded moments of t under the density t^2 on [t0, t1] (mip-NeRF's eq. 7 before its
  rewriting): E[t] = 3/4·(t1^4 - t0^4)/(t1^3 - t0^3), E[t^2] = 3/5·(t1^5 - t0^5)/(t1^3 - t0^3),
  and the offset across the ray of variance radius^2·E[t^2]/4 per axis (a disc of radius
  radius·t)."""
  o, d = np.asarray(o, np.float64)[:, None], np.asarray(d, np.float64)[:, None]
  t0, t1 = np.asarray(t0, np.float64), np.asarray(t1, np.float64)
  cubes = t1 ** 3 - t0 ** 3
  t_mean = 0.75 * (t1 ** 4 - t0 ** 4) / cubes
  t_sq = 0.6 * (t1 ** 5 - t0 ** 5) / cubes
  r_var = np.asarray(radius, np.float64)[:, None] ** 2 * t_sq / 4.0
  mean = o + t_mean[..., None] * d
  if full:
    outer = d[..., :, None] * d[..., None, :]
    cov = ((t_sq - t_mean ** 2)[..., None, None] * outer
           + r_var[..., None, None] * (np.eye(3) - outer / np.sum(d * d, axis=-1)[..., None, None]))
    return mean, cov
  dd = d * d
  var = ((t_sq - t_mean ** 2)[..., None] * dd
         + r_var[..., None] * (1.0 - dd / np.sum(dd, axis=-1, keepdims=True)))
  return mean, var


def _contract_reference(x, radius):
  """float64 L2 contraction, mip-NeRF 360's (2 - 1/n)·x/n with n = |x|/radius outside."""
  n = np.linalg.norm(x, axis=-1, keepdims=True) / radius
  return np.where(n <= 1.0, x, (2.0 - 1.0 / np.maximum(n, 1.0)) * x / np.maximum(n, 1.0))


def test_ipe_field_with_variance_zero_is_the_posenc_field_bit_for_bit():
  ipe, posenc = _field(), _field(**{"model.encoding": "posenc"})
  assert ipe.cones and not posenc.cones
  params = ipe.init(jax.random.PRNGKey(3))
  again = posenc.init(jax.random.PRNGKey(3))  # the same parameters: the same names and shapes
  assert all(np.array_equal(a, b) for a, b in zip(jax.tree_util.tree_leaves(params),
                                                   jax.tree_util.tree_leaves(again)))
  rng = np.random.default_rng(0)
  points = jnp.asarray(rng.uniform(-1.5, 1.5, (5, 7, 3)), jnp.float32)
  viewdirs = jnp.asarray(rng.normal(size=(5, 3)), jnp.float32)
  viewdirs = viewdirs / jnp.linalg.norm(viewdirs, axis=-1, keepdims=True)
  want = jax.jit(posenc.query)(params, points, viewdirs)
  zero = jnp.zeros_like(points)
  got = jax.jit(lambda p, x, v, s: ipe.query(p, x, v, per_sample={'var': s}))(params, points, viewdirs, zero)
  for a, b in zip(got, want):
    np.testing.assert_array_equal(a, b)
  # And variance does change the features (the fine bands fade).
  wide = jax.jit(lambda p, x, v, s: ipe.query(p, x, v, per_sample={'var': s}))(params, points, viewdirs,
                                                               zero + 0.1)
  assert not np.allclose(wide[0], want[0])


def test_field_gaussians_are_the_frustums_of_the_intervals():
  rays = _rays(radius=0.0)
  rays = rays.replace(radii=jnp.asarray([0.0, 1e-3, 0.01, 0.05, 0.2, 0.5], jnp.float32))
  t = jnp.sort(jnp.asarray(np.random.default_rng(1).uniform(2.0, 6.0, (6, 9)), jnp.float32))
  mean, var = jax.jit(_field().gaussians)(rays, t[:, :-1], t[:, 1:])
  ref_mean, ref_var = _frustum_reference(rays.origins, rays.directions, rays.radii, t[:, :-1],
                                         t[:, 1:])
  np.testing.assert_allclose(mean, ref_mean, rtol=1e-5, atol=1e-5)
  # The expanded quotients cancel in float64 too (~1e-16·t^2/hw^2), and the float32 result
  # carries rounding of t^2-sized terms: compared at 1e-3.
  np.testing.assert_allclose(var, ref_var, rtol=1e-3, atol=1e-7)


def test_field_gaussians_in_contracted_space_are_the_linearised_contraction():
  """mip-NeRF 360's: the full covariance through J, then its diagonal (not Σ's diagonal
  through J, which the thin far frustums here make up to ~30x too large)."""
  radius = 1.0
  field = _field(**{"data.contraction": "l2", "data.scene_bound": radius, "num_fine_samples": 0})
  rays = _rays(radius=0.02)
  t = jnp.asarray(np.geomspace(3.0, 40.0, 7)[None].repeat(6, 0), jnp.float32)
  mean, var = jax.jit(field.gaussians)(rays, t[:, :-1], t[:, 1:])
  ref_mean, ref_cov = _frustum_reference(rays.origins, rays.directions, rays.radii, t[:, :-1],
                                         t[:, 1:], full=True)
  np.testing.assert_allclose(mean, ref_mean, rtol=1e-5, atol=1e-5)  # world space
  # J by central differences of the float64 contraction: var'_i = (J Σ Jᵀ)_ii.
  h = 1e-6 * np.maximum(np.linalg.norm(ref_mean, axis=-1), 1.0)[..., None]
  jac = np.stack([(_contract_reference(ref_mean + h * e, radius)
                   - _contract_reference(ref_mean - h * e, radius)) / (2 * h)
                  for e in np.eye(3)], axis=-1)  # [..., i, k]
  want = np.einsum("...ik,...kl,...il->...i", jac, ref_cov, jac)
  np.testing.assert_allclose(var, want, rtol=2e-3, atol=1e-9)
  diagonal = np.sum(jac ** 2 * np.diagonal(ref_cov, axis1=-2, axis2=-1)[..., None, :], axis=-1)
  assert np.max(diagonal / want) > 3.0  # the form the Field no longer uses


def test_renderer_queries_the_gaussians_of_its_samples():
  config = small_config(SMALL, base="mipnerf")
  renderer = builders.make_ray_renderer(config)
  assert renderer.networks == ("coarse",)  # one MLP for both passes (model.shared_fine)
  variables = renderer.init(jax.random.PRNGKey(0))
  params = variables["params"]["coarse"]
  rays = _rays()
  out = jax.jit(renderer.render)(variables, rays)

  def by_hand(rays):
    samples, _ = renderer.sampler.generate(rays)
    t = samples.t
    mean, var = renderer.field.gaussians(rays, t[..., :-1], t[..., 1:])
    rgb, sigma = renderer.field.query(params, mean, rays.viewdirs, per_sample={'var': var})
    return compositing.composite(rgb, placement.per_unit_t(sigma, rays), t)
  want = jax.jit(by_hand)(rays)
  np.testing.assert_allclose(out["coarse"]["rgb"], want["rgb"], rtol=1e-6, atol=1e-7)
  np.testing.assert_allclose(out["coarse"]["depth"], want["depth"], rtol=1e-6, atol=1e-6)
  # The radii reach the encoding: wide cones render otherwise.
  wide = jax.jit(renderer.render)(variables, rays.replace(radii=rays.radii * 50.0))
  assert not np.allclose(wide["fine"]["rgb"], out["fine"]["rgb"])
  with pytest.raises(ValueError, match="radii"):
    renderer.render(variables, rays.replace(radii=None))


@pytest.mark.parametrize("contraction", ["", "l2"])
def test_gradients_are_finite_for_huge_t(contraction):
  overrides = {"num_fine_samples": 0, "pos_encode_dims": 16}
  if contraction:
    overrides.update({"data.contraction": contraction, "data.scene_bound": 1.0})
  field = _field(**overrides)
  params = field.init(jax.random.PRNGKey(1))
  rays = _rays(radius=0.01)
  # Intervals from the scene out to 1e10 (the unbounded sampler's last edge, spacing.py).
  t = jnp.asarray(np.concatenate([[2.0, 3.0, 10.0], np.geomspace(1e3, 1e10, 4)]),
                  jnp.float32)[None].repeat(6, 0)

  def loss(params, radii, origins):
    r = rays.replace(radii=radii, origins=origins)
    mean, var = field.gaussians(r, t[:, :-1], t[:, 1:])
    rgb, sigma = field.query(params, mean, r.viewdirs, per_sample={'var': var})
    return jnp.sum(rgb) + jnp.sum(sigma)
  value, grads = jax.jit(jax.value_and_grad(loss, argnums=(0, 1, 2)))(params, rays.radii,
                                                                       rays.origins)
  assert np.isfinite(value)
  assert all(np.all(np.isfinite(g)) for g in jax.tree_util.tree_leaves(grads))


def test_a_field_of_points_ignores_radii():
  # A plain field renders rays with radii exactly as without them.
  config = small_config({**SMALL, "model.encoding": "posenc"}, base="mipnerf")
  renderer = builders.make_ray_renderer(config)
  variables = renderer.init(jax.random.PRNGKey(0))
  rays = _rays()
  with_radii = jax.jit(renderer.render)(variables, rays)
  without = jax.jit(renderer.render)(variables, rays.replace(radii=None))
  np.testing.assert_array_equal(with_radii["fine"]["rgb"], without["fine"]["rgb"])


# Zip-NeRF's antialiased lattices (model.grid.antialias, model.hash.antialias).

TINY_LATTICE = {"num_samples": 8, "data.scene_bound": 1.5, "model.width": 16,
                "model.grid.resolutions": (8, 16), "model.hash.levels": 3,
                "model.hash.base_resolution": 4, "model.hash.max_resolution": 32,
                "model.hash.log2_size": 10}


def _lattice_field(encoding, antialias, multisample=True, **overrides):
  config = small_config({**TINY_LATTICE, "model.encoding": encoding,
                         f"model.{encoding}.antialias": antialias,
                         f"model.{encoding}.multisample": multisample, **overrides}, base="fast")
  return builders.make_field(config)


@pytest.mark.parametrize("multisample", [True, False])
@pytest.mark.parametrize("encoding", ["grid", "hash"])
def test_antialiased_lattice_at_radius_zero_is_the_plain_lattice(encoding, multisample):
  plain, aa = _lattice_field(encoding, False), _lattice_field(encoding, True, multisample)
  assert aa.cones == ("multisamples" if multisample else "scales") and not plain.cones
  params = plain.init(jax.random.PRNGKey(2))
  rays = _rays(radius=0.0)
  # Zero-length intervals of a zero radius: the six points are the point itself, scale 0.
  t = jnp.asarray(np.random.default_rng(3).uniform(3.0, 5.0, (6, 5)), jnp.float32)
  points, per_sample = aa.cone_inputs(rays, t, t)
  np.testing.assert_array_equal(per_sample["multisamples"][1], 0.0)
  want = jax.jit(plain.query)(params, points, rays.viewdirs)
  got = jax.jit(lambda p, x, v, c: aa.query(p, x, v, per_sample=c))(params, points,
                                                                    rays.viewdirs, per_sample)
  for a, b in zip(got, want):
    np.testing.assert_allclose(a, b, rtol=1e-6, atol=1e-7)


def test_antialiased_features_against_erf_weights_written_here():
  rng = np.random.default_rng(4)
  features = rng.normal(size=(5, 6, 3, 2)).astype(np.float32)  # [N, 6, L, F]
  std = rng.uniform(0.0, 0.3, (5, 6)).astype(np.float32)
  std[0] = 0.0  # points: every level whole
  cells = np.float32([0.4, 0.1, 0.02])
  got = np.asarray(jax.jit(grid.antialiased)(features, std, cells))
  erf = np.vectorize(math.erf)
  with np.errstate(divide="ignore"):
    w = np.where(std[..., None] > 0, erf(cells / (np.sqrt(8.0) * std[..., None])), 1.0)
  want = np.mean(features * w[..., None], axis=1).reshape(5, -1)
  np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
  np.testing.assert_allclose(got[0], features[0].mean(axis=0).reshape(-1), rtol=1e-6)


def test_centre_samples_are_the_multisamples_mean_with_its_scale():
  # The frustum's mean is the six multisamples' mean (their balance, cones.multisamples); its
  # scale is the one a multisample at the mean t would get: radius·t/sqrt(2).
  rays = _rays(radius=0.03)
  rng = np.random.default_rng(5)
  t0 = jnp.asarray(rng.uniform(2.0, 5.0, (6, 4)), jnp.float32)
  t1 = t0 + jnp.asarray(rng.uniform(0.01, 0.5, (6, 4)), jnp.float32)
  six, _ = cones.multisamples(rays.origins, rays.directions, rays.radii, t0, t1)
  one, scale = cones.centre_samples(rays.origins, rays.directions, rays.radii, t0, t1)
  assert one.shape == (6, 4, 1, 3) and scale.shape == (6, 4, 1)
  np.testing.assert_allclose(one[..., 0, :], np.mean(np.asarray(six), axis=-2), atol=2e-5)
  mu, hw = (np.asarray(t0) + np.asarray(t1)) / 2, (np.asarray(t1) - np.asarray(t0)) / 2
  t_mean = mu + 2 * mu * hw ** 2 / (3 * mu ** 2 + hw ** 2)  # mip-NeRF's, written here
  np.testing.assert_allclose(scale[..., 0], 0.03 * t_mean / np.sqrt(2.0), rtol=1e-5)


def _trilinear_reference(lattice, unit):
  """float64 [..., F]: lattice float [R, R, R, F] at unit float64 [..., 3] in [0, 1], by the
  8 corners' products of weights (grid.py's convention: R points over [0, 1])."""
  r = lattice.shape[0]
  x = np.clip(unit, 0.0, 1.0) * (r - 1)
  low = np.minimum(np.floor(x), r - 2).astype(int)
  frac = x - low
  out = 0.0
  for corner in itertools.product((0, 1), repeat=3):
    c = np.asarray(corner)
    w = np.prod(np.where(c == 1, frac, 1 - frac), axis=-1, keepdims=True)
    i = low + c
    out = out + w * np.float64(lattice)[i[..., 0], i[..., 1], i[..., 2]]
  return out


class _GivenFeatures:
  """An encoding (protocol.Encoding's calls that LatticeHead makes) handing the head features
  computed beforehand, float [..., L·F], and the real encoding's box."""

  def __init__(self, features, real):
    self.h, self.real = features, real

  def features(self, module, points, weights=None, **per_sample):
    del module, points, weights, per_sample
    return self.h

  def inside(self, points):
    return self.real.inside(points)


@pytest.mark.parametrize("multisample", [True, False])
def test_antialiased_grid_renders_its_reference_pass(multisample):
  """The anti-aliased dense grid's render against a pass written here: each level's features
  interpolated at the six multisamples (or the frustum's mean: multisample False) by the 8
  corners, weighted by erf(h_l / (sqrt(8)·std)) with h_l = 2·bound / (R_l - 1) and std the
  multisample's scale times 0.5 (camp_zipnerf's unscented_scale_mult), averaged, then the
  field's own head; and the weights do differ from 1 there (levels are faded)."""
  config = small_config({**TINY_LATTICE, "model.grid.antialias": True,
                         "model.grid.multisample": multisample}, base="fast")
  renderer = builders.make_ray_renderer(config)
  variables = renderer.init(jax.random.PRNGKey(0))
  params = dict(variables["params"]["coarse"])
  rng = np.random.default_rng(6)
  resolutions = config.model.grid.resolutions
  for r in resolutions:  # features of order 1, so that the weights show in the colour
    params[f"grid_{r}"] = jnp.asarray(rng.normal(size=params[f"grid_{r}"].shape), jnp.float32)
  variables = {**variables, "params": {"coarse": params}}
  rays = _rays(radius=0.2)  # scales (halved) of ~0.1-0.3 against cells of 0.43 and 0.2
  out = jax.jit(renderer.render)(variables, rays)["coarse"]

  samples, _ = renderer.sampler.generate(rays)
  t = samples.t
  sampler = cones.multisamples if multisample else cones.centre_samples
  points, std = (np.float64(a) for a in sampler(rays.origins, rays.directions, rays.radii,
                                                t[..., :-1], t[..., 1:]))
  std = 0.5 * std  # Zip-NeRF's configs: unscented_scale_mult = 0.5
  bound = config.data.scene_bound
  erf = np.vectorize(math.erf)
  levels = []
  for r in resolutions:
    w = erf(2 * bound / (r - 1) / (np.sqrt(8.0) * std))[..., None]  # [R, S, M, 1]
    levels.append(np.mean(w * _trilinear_reference(params[f"grid_{r}"], (points / bound + 1) / 2),
                          axis=-2))
    assert 0.05 < w.min() < 0.9  # some samples' levels faded, not gone
  features = jnp.asarray(np.concatenate(levels, axis=-1), jnp.float32)
  field = renderer.field
  mean, _ = field.cone_inputs(rays, t[..., :-1], t[..., 1:])
  network = field.network.clone(encoding=_GivenFeatures(features, field.network.encoding))
  rgb, raw_sigma = network.apply({"params": params}, mean)
  sigma = field._activate(raw_sigma, None)
  want = compositing.composite(rgb, placement.per_unit_t(sigma, rays), t)
  np.testing.assert_allclose(out["rgb"], want["rgb"], rtol=1e-4, atol=1e-5)
  np.testing.assert_allclose(out["depth"], want["depth"], rtol=1e-4, atol=1e-4)


@pytest.mark.parametrize("contraction,multisample", [("", True), ("l2", True), ("", False)])
def test_antialiased_grid_has_finite_gradients(contraction, multisample):
  overrides = {"data.contraction": contraction, "data.scene_bound": 1.0} if contraction else {}
  config = small_config({**TINY_LATTICE, "model.grid.antialias": True,
                         "model.grid.multisample": multisample, **overrides}, base="fast")
  renderer = builders.make_ray_renderer(config)
  variables = renderer.init(jax.random.PRNGKey(0))
  rays = _rays(radius=0.02)

  def loss(params, radii):  # as training renders: with a key (the multisamples turned)
    out = renderer.render({**variables, "params": params}, rays.replace(radii=radii),
                          jax.random.PRNGKey(2))
    return jnp.sum(renderer_lib.final(out)["rgb"])
  value, grads = jax.jit(jax.value_and_grad(loss, argnums=(0, 1)))(variables["params"],
                                                                    rays.radii)
  assert np.isfinite(value)
  assert all(np.all(np.isfinite(g)) for g in jax.tree_util.tree_leaves(grads))


def test_multisamples_turn_at_random_while_training_and_not_at_evaluation():
  """Zip-NeRF's training jitter through the Field: cone_inputs without a key (evaluation) is
  the deterministic hexagons of cones.multisamples(key=None) bit for bit, and the same twice;
  with a key each frustum's hexagon is mirrored and turned at random: the same for one key,
  different for another, the scales unchanged. Whatever the key, the six points keep the
  frustum's moments, against the float64 moments written here (_frustum_reference): their mean
  (to float32 rounding), their variance along the ray and their mean squared offset across it
  (exactly, to rounding), and their covariance within the hexagon's own 0.65·hw/mu in whitened
  terms (tests/cameras/test_cones.py measures that bound)."""
  config = small_config({**TINY_LATTICE, "model.grid.antialias": True}, base="fast")
  field = builders.make_ray_renderer(config).field
  assert field.cones == "multisamples"
  rays = _rays(radius=0.1)
  t = jnp.sort(jnp.asarray(np.random.default_rng(7).uniform(2.0, 6.0, (6, 9)), jnp.float32))
  t0, t1 = t[:, :-1], t[:, 1:]
  draw = jax.jit(lambda key: field.cone_inputs(rays, t0, t1, key)[1]["multisamples"])
  evaluation = draw(None)
  # Op by op (no jit on either side: one compilation may fuse and round otherwise).
  eager = field.cone_inputs(rays, t0, t1)[1]["multisamples"]
  points, scales = cones.multisamples(rays.origins, rays.directions, rays.radii, t0, t1)
  want = (points, 0.5 * scales)  # the level weights read half the scale (unscented_scale_mult)
  for a, b, c in zip(eager, want, evaluation):
    np.testing.assert_array_equal(a, b)
    np.testing.assert_allclose(c, b, rtol=0, atol=1e-6 * np.abs(b).max())
  np.testing.assert_array_equal(draw(None)[0], evaluation[0])
  first, again, other = draw(jax.random.PRNGKey(0)), draw(jax.random.PRNGKey(0)), draw(
      jax.random.PRNGKey(1))
  np.testing.assert_array_equal(first[0], again[0])
  moved = lambda a, b: np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1) > 1e-4
  assert np.mean(moved(first[0], other[0])) > 0.9  # nearly every point elsewhere
  assert np.mean(moved(first[0], evaluation[0])) > 0.9
  np.testing.assert_array_equal(first[1], evaluation[1])  # scales: radius·t_j/sqrt(2)/2

  ref_mean, ref_cov = _frustum_reference(rays.origins, rays.directions, rays.radii, t0, t1,
                                         full=True)
  d = np.asarray(rays.directions, np.float64)[:, None, :]
  hw_over_mu = np.asarray((t1 - t0) / (t1 + t0), np.float64)
  for points in (evaluation[0], first[0], other[0]):
    points = np.asarray(points, np.float64)  # [6 rays, 8 frustums, 6 points, 3]
    mean = points.mean(axis=-2)
    np.testing.assert_allclose(mean, ref_mean, rtol=0, atol=1e-5 * np.abs(ref_mean).max())
    c = points - mean[..., None, :]
    cov = np.einsum("...ji,...jk->...ik", c, c) / 6.0
    along = lambda m: np.einsum("...i,...ij,...j->...", d, m, d) / np.sum(d * d, -1)
    np.testing.assert_allclose(along(cov), along(ref_cov), rtol=1e-3)
    np.testing.assert_allclose(np.trace(cov, axis1=-2, axis2=-1),
                               np.trace(ref_cov, axis1=-2, axis2=-1), rtol=1e-3)
    # Whitened: the largest |eigenvalue| of C^(-1/2) (cov - C) C^(-1/2), C the reference.
    w, v = np.linalg.eigh(ref_cov)
    inv_sqrt = v @ (w[..., None] ** -0.5 * np.swapaxes(v, -1, -2))
    err = np.max(np.abs(np.linalg.eigvalsh(inv_sqrt @ (cov - ref_cov) @ inv_sqrt)), axis=-1)
    assert np.all(err <= 0.65 * hw_over_mu + 1e-3), np.max(err / hw_over_mu)


def test_the_renderer_hands_its_key_to_the_multisamples(monkeypatch):
  """RayRenderer.render's key reaches Field.cone_inputs (fold_in(pass key, MULTISAMPLE_KEY)):
  while training (a key) each pass's multisamples are turned off the deterministic hexagons of
  the same intervals, by a key of their own for each render key (another key turns them
  otherwise, the same key alike); at evaluation (no key) they are the deterministic ones."""
  config = small_config({**TINY_LATTICE, "model.grid.antialias": True}, base="fast")
  renderer = builders.make_ray_renderer(config)
  field = renderer.field
  assert field.cones == "multisamples"
  calls, original = [], type(field).cone_inputs

  def recording(self, rays, t0, t1, key=None):
    out = original(self, rays, t0, t1, key)
    calls.append((t0, t1, key, out[1]["multisamples"][0]))
    return out

  monkeypatch.setattr(type(field), "cone_inputs", recording)
  variables = renderer.init(jax.random.PRNGKey(0))
  rays = _rays(radius=0.1)
  passes = {}
  for name, key in (("one", jax.random.PRNGKey(1)), ("again", jax.random.PRNGKey(1)),
                    ("other", jax.random.PRNGKey(2)), ("evaluation", None)):
    calls.clear()
    renderer.render(variables, rays, key)  # op by op: the calls see arrays, not tracers
    passes[name] = list(calls)
  assert len(passes["one"]) >= 1
  rays_hex = lambda t0, t1, key: original(field, rays, t0, t1, key)[1]["multisamples"][0]
  moved = lambda a, b: np.mean(np.linalg.norm(np.asarray(a) - np.asarray(b), axis=-1) > 1e-4)
  for (t0, t1, key, points), (_, _, again_key, again) in zip(passes["one"], passes["again"]):
    assert key is not None
    np.testing.assert_array_equal(key, again_key)
    np.testing.assert_array_equal(points, again)
    assert moved(points, rays_hex(t0, t1, None)) > 0.9  # turned at random, nearly every point
  for (t0, t1, key, points), (_, _, other_key, _) in zip(passes["one"], passes["other"]):
    assert not np.array_equal(key, other_key)
    assert moved(points, rays_hex(t0, t1, other_key)) > 0.9  # the other key turns otherwise
  for t0, t1, key, points in passes["evaluation"]:
    assert key is None
    np.testing.assert_array_equal(points, rays_hex(t0, t1, None))


def test_image_renderer_compiles_and_draws_rays_with_radii():
  # Its compile step draws a probe ray of the kind it will draw: with a radius for cones.
  config = small_config(SMALL, base="mipnerf")
  renderer = builders.make_ray_renderer(config)
  variables = renderer.init(jax.random.PRNGKey(0))
  settings = dataclasses.replace(builders.image_settings(config), chunk=16)
  draw = image_renderer.make_image_renderer(renderer, settings)(variables)
  list(draw.compile_steps())
  rays = _rays()
  out = draw(rays)
  want = jax.jit(renderer.render)(variables, rays)["fine"]["rgb"]
  np.testing.assert_allclose(out["rgb"], want, rtol=1e-5, atol=1e-6)
