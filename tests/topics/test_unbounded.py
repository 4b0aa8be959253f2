"""Unbounded scenes end to end: the sampler's placement, the field's contraction, the scene
extent found from the data, and the one line when rays leave a bounded box."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.fields import contraction
from nerf_jax.fields.encodings import grid, posenc
from nerf_jax.fields.networks import lattice
from nerf_jax.fields.protocol import NetworkSettings
from nerf_jax.run import builders, experiment, from_data
from nerf_jax.samplers import occupancy, placement, spacing
from nerf_jax.fields.field import Field
from nerf_jax.cameras.rays import Rays
from tests.helpers import jitted, small_config


def _rays(num=64, seed=0):
  rng = np.random.default_rng(seed)
  origins = rng.normal(size=(num, 3)).astype(np.float32) * 2.0
  directions = rng.normal(size=(num, 3)).astype(np.float32)
  return Rays.create(jnp.asarray(origins), jnp.asarray(directions), 0.1, 5.0)


@pytest.mark.parametrize("kind", ["l2", "linf"])
def test_contracted_placement_is_linear_inside_and_in_disparity_beyond(kind):
  rays = _rays()
  placed = placement.Sampler(32, scene_bound=1.5, contraction=kind, inner_fraction=0.25)
  t = placed.place(rays).t
  t_inner = contraction.inner_exit(rays.origins, rays.directions, 1.5, kind)
  expected = spacing.stratified_unbounded(rays.near, t_inner, jnp.inf, 32, rays.shape,
                                           inner_fraction=0.25)
  np.testing.assert_array_equal(t, expected)
  # The rays run to (effectively) infinity, not to their far bound, and stay sorted and finite.
  assert np.all(np.isfinite(t)) and np.all(np.diff(t, axis=-1) >= 0)
  assert np.all(t[:, -1] >= 1e9)
  # A bounded sampler stops at the box: the contraction is what lets samples go beyond.
  bounded = placement.Sampler(32, scene_bound=1.5).place(rays).t
  assert np.all(bounded[:, -1] <= 5.0 + 1e-5)


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_the_field_sees_contracted_positions():
  encoding = grid.DenseGrid(grid.Settings(resolutions=(4,), features=2), grid.Space(3.0))
  network = lattice.LatticeHead(encoding, NetworkSettings(width=8))
  field = Field(network, posenc.Frequency(2), contraction="linf", inner_radius=1.5)
  points = jnp.array([[0.5, -0.2, 0.1], [30.0, 0.0, -2.0], [1e8, 1e8, 0.0]], jnp.float32)
  encoded = jitted(field.network_points)(points)
  np.testing.assert_allclose(encoded, contraction.contract(points, 1.5, "linf"), rtol=1e-6)
  assert np.all(np.abs(encoded) <= 3.0)  # inside the grids' box of half-size 2 x 1.5
  params = jitted(field.init)(jax.random.PRNGKey(0))
  _, sigma = jitted(field.query)(params, points[:, None, :], jnp.zeros_like(points))
  assert np.all(np.isfinite(sigma))
  # Without the contraction, far points fall outside the grids and get no density at all.
  plain = Field(network, posenc.Frequency(2))
  _, far_sigma = jitted(plain.query)(params, points[1:, None, :], jnp.zeros_like(points[1:]))
  assert np.all(far_sigma == 0.0)


def test_auto_scene_bound_is_the_cameras_box_and_the_grids_span_twice_it(capsys):
  exp = experiment.setup(small_config({"data.scene_bound": -1.0, "data.contraction": "linf"}))
  cameras = float(np.max(np.abs(exp.train_ds.poses[:, :3, 3])))
  assert exp.config.data.scene_bound == pytest.approx(cameras, abs=1e-4)
  assert exp.renderer.sampler.scene_bound == exp.config.data.scene_bound
  assert "scene extent: box ±" in capsys.readouterr().out
  assert exp.renderer.field.inner_radius == pytest.approx(cameras, abs=1e-4)


def _photos(exp):
  """`exp` as if its images were photos: no opacity, so where rays end is unknown."""
  return dataclasses.replace(exp, train_ds=dataclasses.replace(exp.train_ds, accs=None))


def test_a_box_that_cuts_most_rays_says_so_in_one_line(capsys):
  exp = experiment.setup(small_config({"data.scene_bound": 0.5}))  # the cameras sit at radius 4
  assert "leave the scene box" not in capsys.readouterr().out  # opacity: the rest is empty
  from_data.warn_if_cut(_photos(exp))
  lines = [l for l in capsys.readouterr().out.splitlines() if "leave the scene box" in l]
  assert len(lines) == 1 and "data.contraction" in lines[0]
  # A box holding the whole of [near, far] (radius 4 + far 6) cuts nothing.
  from_data.warn_if_cut(_photos(experiment.setup(small_config({"data.scene_bound": 10.0}))))
  assert "leave the scene box" not in capsys.readouterr().out
  # Contracted: nothing is cut.
  exp = experiment.setup(small_config({"data.scene_bound": 0.5, "data.contraction": "linf"}))
  from_data.warn_if_cut(_photos(exp))
  assert "leave the scene box" not in capsys.readouterr().out


def test_contraction_refuses_what_it_cannot_do_yet():
  config = small_config({"data.scene_bound": 1.5, "data.contraction": "linf",
                         "num_fine_samples": 8})
  with pytest.raises(ValueError, match="contraction"):
    builders.make_sampler(config)


def test_occupancy_in_contracted_space_samples_only_occupied_cells():
  # Occupied: the contracted cells of a shell between world radius 3 and 6 (L-inf), i.e.
  # contracted |c| in [1.5 * (2 - 1/2), 1.5 * (2 - 1/4)] = [2.25, 2.625].
  oc = occupancy.OccupancySettings(resolution=16, candidates=128)
  rs = placement.Sampler(16, scene_bound=1.5, occupancy=oc, contraction="linf")
  centres = np.asarray(occupancy.cell_centres(16, rs.grid_bound))
  radius = np.max(np.abs(centres), axis=-1)
  grid = np.where((radius > 2.25) & (radius < 2.625), 10.0, 0.0).astype(np.float32)
  rays = Rays.create(jnp.zeros((32, 3)), jnp.asarray(np.random.default_rng(1).normal(
      size=(32, 3)), jnp.float32), 0.1, 5.0)
  placed = jitted(rs.place)(rays, jax.random.PRNGKey(0), jnp.asarray(grid))
  world = placement.points(rays, placed.distances)[np.asarray(placed.valid)]
  assert len(world) > 32  # every ray crosses the shell
  # Each valid sample lies in the occupied shell (up to a cell of contracted space, 0.1875).
  cells = np.max(np.abs(np.asarray(contraction.contract(world, 1.5, "linf"))), axis=-1)
  assert np.all((cells > 2.25 - 0.19) & (cells < 2.625 + 0.19))
  assert np.all(np.isfinite(placed.t)) and np.all(np.diff(placed.t, axis=-1) >= 0)


def test_a_capture_video_follows_its_own_trajectory():
  from nerf_jax.cameras import camera_paths  # pylint: disable=import-outside-toplevel
  angles = np.linspace(0.0, np.pi, 30)
  poses = np.tile(np.eye(4, dtype=np.float32), (30, 1, 1))
  poses[:, 0, 3], poses[:, 1, 3] = 3 * np.cos(angles), 3 * np.sin(angles)  # an arc, in order
  dataset = type("Captured", (), {"poses": poses})()
  path = camera_paths.video_poses(dataset, 60, False, -30.0, 4.0, trajectory=True)
  assert 50 <= len(path) <= 61
  np.testing.assert_allclose(path[0], poses[0], atol=1e-6)
  np.testing.assert_allclose(path[-1], poses[-1], atol=1e-6)
  # On the arc (radius 3) all the way, in order, with no jumps: the capture's own path.
  np.testing.assert_allclose(np.linalg.norm(path[:, :2, 3], axis=-1), 3.0, atol=0.05)
  steps = np.linalg.norm(np.diff(path[:, :3, 3], axis=0), axis=-1)
  assert steps.max() < 3.0 * np.median(steps)
  # Not an orbit about the origin at the configured radius.
  orbit = camera_paths.video_poses(dataset, 60, False, -30.0, 4.0)  # the configs' orbit
  assert not np.allclose(path, orbit[:len(path)], atol=0.1)


def test_an_automatic_bounded_box_is_the_grids_box_too():
  exp = experiment.setup(small_config({"data.scene_bound": -1.0, "model.encoding": "grid"}))
  cameras = float(np.max(np.abs(exp.train_ds.poses[:, :3, 3])))  # built-in: no aabb
  assert exp.config.data.scene_bound == pytest.approx(cameras, abs=1e-4)
  assert exp.renderer.field.network.encoding.space.bound == pytest.approx(cameras, abs=1e-4)
  assert exp.renderer.sampler.scene_bound == exp.config.data.scene_bound


def test_the_video_path_is_chosen_by_the_data():
  from nerf_jax.run import outputs  # pylint: disable=import-outside-toplevel
  exp = experiment.setup(small_config())
  assert not outputs.follows_trajectory(exp)  # built-in scene: the orbit
  box = np.array([[-1.0] * 3, [1.0] * 3], np.float32)
  captured = dataclasses.replace(exp, train_ds=dataclasses.replace(exp.train_ds, aabb=box))
  assert outputs.follows_trajectory(captured)  # a transforms.json capture: its own path
  captured.config.render.video_path = "orbit"
  assert not outputs.follows_trajectory(captured)
  captured.config.render.video_path = "circle"
  with pytest.raises(ValueError, match="video_path"):
    outputs.follows_trajectory(captured)
