"""The vector-matrix factorised field (tensorf.py, read by networks/lattice.LatticeHead): its reads against a dense
grid built from the same factors, its gradients, and a training step through the renderer."""

import jax
import jax.numpy as jnp
import numpy as np
import optax

from nerf_jax.fields.encodings import grid, tensorf
from nerf_jax.run.signature import model_signature
from nerf_jax.bench import encodings as bench_encodings
from nerf_jax.fields.networks.lattice import LatticeHead
from nerf_jax.fields.protocol import NetworkSettings
from tests.helpers import grey_view_loss, jitted, ray_renderer, small_config
from tests.helpers import trilinear_brute


def _factors(axis_points, rank, seed=0):
  rng = np.random.default_rng(seed)
  plane_shapes, line_shapes = tensorf.shapes(axis_points, rank)
  planes = [rng.standard_normal(s).astype(np.float32) for s in plane_shapes]
  lines = [rng.standard_normal(s).astype(np.float32) for s in line_shapes]
  return planes, lines


def _dense_mode(plane, line, mode):
  """The dense grid [Rx, Ry, Rz, C] whose values at the lattice are plane × line of `mode`."""
  (a, b), c = tensorf.MODES[mode]
  axes = "xyz"
  spec = f"{axes[a]}{axes[b]}k,{axes[c]}k->xyzk"
  return np.einsum(spec, plane, line)


def test_vm_features_equal_trilinear_reads_of_the_dense_product():
  # Trilinear interpolation is separable, so interpolating the dense product of a plane and a
  # line equals the product of their bilinear and linear interpolations, at any position.
  axis_points, rank = (5, 7, 4), 3
  planes, lines = _factors(axis_points, rank)
  rng = np.random.default_rng(1)
  unit = rng.random((40, 3)).astype(np.float32)
  unit[0], unit[1] = 0.0, 1.0  # the box's corners (the upper lattice points)
  unit[2] = [-0.2, 0.5, 1.3]  # outside: clamped to the surface
  got = np.asarray(tensorf.vm_features([jnp.asarray(p) for p in planes],
                                       [jnp.asarray(l) for l in lines], jnp.asarray(unit)))
  assert got.shape == (40, 3 * rank)
  for mode in range(3):
    dense = _dense_mode(planes[mode], lines[mode], mode)
    want = np.stack([trilinear_brute(dense, u) for u in unit])
    np.testing.assert_allclose(got[:, mode * rank:(mode + 1) * rank], want, rtol=1e-4,
                               atol=1e-4)


def test_vm_gradients_match_the_dense_product_and_stay_on_the_touched_cells():
  axis_points, rank = (6, 6, 6), 2
  planes, lines = _factors(axis_points, rank, seed=2)
  unit = jnp.array([[0.3, 0.61, 0.17], [0.9, 0.05, 0.5]], jnp.float32)
  loss = lambda ps, ls: jnp.sum(tensorf.vm_features(ps, ls, unit) ** 2)
  gp, gl = jax.grad(loss, argnums=(0, 1))([jnp.asarray(p) for p in planes],
                                         [jnp.asarray(l) for l in lines])
  eps = 1e-3  # central differences on one plane value that a point reads
  p0 = [jnp.asarray(p) for p in planes]
  bumped = lambda s: [p.at[1, 3, 0].add(s) if m == 0 else p for m, p in enumerate(p0)]
  numeric = (loss(bumped(eps), lines) - loss(bumped(-eps), lines)) / (2 * eps)
  np.testing.assert_allclose(float(gp[0][1, 3, 0]), float(numeric), rtol=2e-2, atol=1e-3)
  for g in [*gp, *gl]:
    assert bool(jnp.all(jnp.isfinite(g)))
  # Two points touch at most 4 plane corners each: the rest of the plane gets no gradient.
  assert 0 < int(jnp.sum(jnp.any(gp[0] != 0, axis=-1))) <= 8


TENSORF_DEBUG = {"model.encoding": "tensorf", "model.tensorf.resolutions": (8, 16),
                 "model.tensorf.rank": 4, "model.density_activation": "softplus",
                 "data.scene_bound": 1.5}


def test_tensorf_model_shapes_box_and_one_training_step():
  config = small_config(TENSORF_DEBUG)
  rr = ray_renderer(config)
  assert isinstance(rr.field.network, LatticeHead)
  assert isinstance(rr.field.network.encoding, tensorf.TensoRF)
  params = jitted(rr.init)(jax.random.PRNGKey(0))["params"]
  coarse = params["coarse"]
  assert coarse["plane_16_0"].shape == (16, 16, 4) and coarse["line_8_2"].shape == (8, 4)
  signature = model_signature(config)
  assert signature["encoding"] == "tensorf" and signature["tensorf_rank"] == 4
  assert signature["tensorf_resolutions"] == [8, 16]

  tx = optax.adam(1e-2)
  loss_and_grad = jax.jit(jax.value_and_grad(grey_view_loss(rr)))
  state, p = tx.init(params), params
  losses = []
  for _ in range(30):
    loss, grads = loss_and_grad(p)
    updates, state = tx.update(grads, state)
    p = optax.apply_updates(p, updates)
    losses.append(float(loss))
  assert all(np.isfinite(losses)) and losses[-1] < 0.2 * losses[0], losses
  assert float(jnp.max(jnp.abs(p["coarse"]["plane_16_1"] - coarse["plane_16_1"]))) > 1e-3


def test_tensorf_box_cells_and_out_of_box_density():
  box = (-1.0, -0.5, -0.25, 1.0, 0.5, 0.25)
  encoding = tensorf.TensoRF(tensorf.Settings(resolutions=(9,), rank=2), grid.Space(box=box))
  model = LatticeHead(encoding, NetworkSettings())
  points = jnp.array([[0.0, 0.0, 0.0], [0.0, 0.0, 0.3]])  # inside; beyond the box in z
  params = model.init(jax.random.PRNGKey(0), points)["params"]
  assert grid.axis_resolutions(9, (box[:3], box[3:])) == (9, 5, 3)
  assert params["plane_9_0"].shape == (9, 5, 2) and params["line_9_0"].shape == (3, 2)
  _, raw_sigma = model.apply({"params": params}, points)
  assert float(raw_sigma[1]) == -1e5 and np.isfinite(float(raw_sigma[0]))


def test_encodings_microbenchmark_counts_the_tables_it_times():
  for kind, resolutions, width, want in (("dense", (4, 8), 2, 4 ** 3 * 2 + 8 ** 3 * 2),
                                         ("tensorf", (8,), 2, 3 * 8 * 8 * 2 + 3 * 8 * 2)):
    count, forward_ms, step_ms = bench_encodings.measure_one(kind, resolutions, width,
                                                            samples=64, repeats=1)
    assert count == want and forward_ms > 0 and step_ms > 0
