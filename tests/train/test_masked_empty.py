"""loss.masked_empty: the mean opacity of a batch's masked rays, against a loop written here;
nothing from kept rays, nothing without masks; its gradient pulls only the masked rays'
density; a patch batch of masked data carries masked rays for it to act on."""

import jax
import jax.numpy as jnp
import numpy as np

from nerf_jax.render import compositing
from nerf_jax.run import config_lib
from nerf_jax.train import losses
from nerf_jax.train.losses import masked_empty


def _inputs(acc, mask):
  return losses.LossInputs({"coarse": {"acc": jnp.asarray(acc, jnp.float32)}},
                           jnp.zeros((len(acc), 3)), None, {},
                           mask=None if mask is None else jnp.asarray(mask, jnp.float32))


def test_the_masked_rays_mean_opacity_by_a_loop():
  rng = np.random.default_rng(0)
  acc, mask = rng.random(64), (rng.random(64) > 0.4).astype(np.float32)
  term = masked_empty.build(masked_empty.Settings(weight=0.3), None)
  loss, stats = term(_inputs(acc, mask))
  opacities = [a for a, m in zip(acc, mask) if m == 0]
  np.testing.assert_allclose(float(loss), 0.3 * sum(opacities) / len(opacities), rtol=1e-6)
  np.testing.assert_allclose(float(stats["share"]), len(opacities) / 64, rtol=1e-6)
  # Kept rays alone, or no masks: nothing to pull, a zero loss.
  assert float(term(_inputs(acc, np.ones(64)))[0]) == 0.0
  assert float(term(_inputs(acc, None))[0]) == 0.0
  assert masked_empty.build(masked_empty.Settings(), None) is None  # weight 0: off


def test_its_gradient_reaches_the_masked_rays_density_alone():
  # Two rays of 8 samples: only the masked one's densities get a gradient, and it lowers them.
  t = jnp.linspace(2.0, 6.0, 9)[None].repeat(2, 0)
  term = masked_empty.MaskedEmpty(1.0)

  def loss(sigma):
    out = compositing.composite(jnp.ones((2, 8, 3)) * 0.5, sigma, t)
    inputs = losses.LossInputs({"coarse": out}, jnp.zeros((2, 3)), None, {},
                               mask=jnp.array([1.0, 0.0]))
    return term(inputs)[0]
  grad = jax.grad(loss)(jnp.full((2, 8), 0.3))
  assert np.all(np.asarray(grad[0]) == 0.0) and np.all(np.asarray(grad[1]) > 0.0)


def test_a_config_field_and_a_default_term():
  config = config_lib.load("default")
  assert config.loss.masked_empty.weight == 0.0 and "masked_empty" in config.loss.terms
