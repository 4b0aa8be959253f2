"""The flat draws are bit for bit jax's shaped draws, in both of jax's threefry modes."""

import jax
import numpy as np
import pytest

from nerf_jax.backend import draws

SHAPES = [(), (5, 3), (2, 3, 2, 2)]  # each shaped draw of rank 4 costs ~2.7 s to compile


@pytest.mark.parametrize("partitionable", [True, False])
def test_flat_draws_equal_shaped_draws(partitionable):
  key = jax.random.PRNGKey(11)
  with jax.threefry_partitionable(partitionable):
    for shape in SHAPES:
      np.testing.assert_array_equal(draws.normal(key, shape), jax.random.normal(key, shape))
      assert draws.normal(key, shape).shape == shape


def test_flat_uniform_equals_shaped_uniform_with_its_bounds():
  key = jax.random.PRNGKey(5)
  np.testing.assert_array_equal(draws.uniform(key, (4, 3, 2), minval=-2.0, maxval=3.0),
                                jax.random.uniform(key, (4, 3, 2), minval=-2.0, maxval=3.0))


def test_draws_inside_jit_match_eager():
  key = jax.random.PRNGKey(2)
  jitted = jax.jit(lambda k: draws.uniform(k, (3, 4, 5)))
  np.testing.assert_array_equal(jitted(key), jax.random.uniform(key, (3, 4, 5)))


def test_a_scaled_normal_init_compiled_whole_equals_it_run_op_by_op():
  """Without the barrier, XLA folds the scale into the normal's constants inside a larger
  program (1 ulp off); Field.init is jitted and must keep the values of eager inits."""
  key, shape = jax.random.PRNGKey(0), (8, 8, 8, 4)
  init = draws.normal_init(1e-2)
  eager = init(key, shape)
  np.testing.assert_array_equal(jax.jit(init, static_argnums=1)(key, shape), eager)
  np.testing.assert_array_equal(eager, 1e-2 * draws.normal(key, shape))  # as before the barrier
