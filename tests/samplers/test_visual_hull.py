"""The visual hull: projection inverts the camera rays; carving a sphere's masks keeps every cell
the sphere touches and removes what no view covers; transient masks never carve; a subject's
masks, hidden in some photos by passers-by, carved by vote (the one mask vote, each photo
through its own camera, against a vote written here; its windows and footprints); the gate and
every rendering path give no density outside the hull (closed-form optical depths); grids over a
tighter, non-cubic box interpolate as brute force; a run with data.visual_hull samples only
inside the hull."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras import rays
from nerf_jax.cameras.cameras import Cameras
from nerf_jax.cameras.rays import Rays
from nerf_jax.data.dataset import Dataset
from nerf_jax.render import image_renderer, renderer
from nerf_jax.fields.networks import lattice
from nerf_jax.fields.encodings import grid
from nerf_jax.fields.protocol import NetworkSettings
from nerf_jax.run import builders, experiment, from_data
from nerf_jax.run.signature import init_state, model_signature
from nerf_jax.samplers import occupancy, placement, visual_hull
from tests.helpers import StandInNetwork, TINY_GRID, jitted, ray_renderer, small_config
from tests.helpers import trilinear_brute


def _views(count, radius=4.0):
  """Camera-to-world poses float32 [count, 4, 4] spread over a sphere (Fibonacci), looking at
  the origin."""
  golden = np.pi * (3.0 - np.sqrt(5.0))
  poses = []
  for k in range(count):
    z = 1.0 - 2.0 * (k + 0.5) / count
    theta, phi = golden * k, np.degrees(np.arcsin(z))
    poses.append(np.asarray(rays.pose_spherical(np.degrees(theta), -phi, radius)))
  return np.stack(poses).astype(np.float32)


def _sphere_masks(poses, size, focal, radius):
  """float32 [N, size, size]: 1 where a pixel's centre ray hits the sphere of `radius` at the
  origin (closed-form ray-sphere test: distance from the origin to the ray's line)."""
  masks = []
  for pose in poses:
    o, d = rays.get_rays(size, size, focal, jnp.asarray(pose), pixel_center=0.5)
    o, d = np.asarray(o), np.asarray(d)
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    closest = np.sum(-o * d, axis=-1)  # t of the point nearest the origin (cameras outside)
    miss = np.linalg.norm(o + closest[..., None] * d, axis=-1)
    masks.append((miss <= radius).astype(np.float32))
  return np.stack(masks)


def test_project_inverts_pixel_rays():
  intrinsics = (70.0, 60.0, 31.0, 27.5)
  pose = _views(7)[3]
  rng = np.random.default_rng(0)
  col, row = rng.uniform(0, 64, 20).astype(np.float32), rng.uniform(0, 48, 20).astype(np.float32)
  r = rays.pixel_rays(jnp.asarray(col), jnp.asarray(row), 48, 64, intrinsics, jnp.asarray(pose),
                      2.0, 6.0, 0.5)
  t = rng.uniform(1.0, 5.0, 20).astype(np.float32)
  points = r.origins + r.directions * t[:, None]  # camera-space directions have z = -1
  got_col, got_row, depth = visual_hull.project(points, jnp.asarray(pose), intrinsics, 0.5)
  np.testing.assert_allclose(got_col, col, atol=2e-3)
  np.testing.assert_allclose(got_row, row, atol=2e-3)
  np.testing.assert_allclose(depth, t, rtol=1e-5)


def test_carving_a_sphere_keeps_what_it_touches_and_removes_the_rest():
  size, focal, ball, bound, res = 48, 60.0, 0.5, 1.0, 24
  poses = _views(30)
  hull = np.asarray(visual_hull.carve(_sphere_masks(poses, size, focal, ball), poses,
                                      (focal, focal, size / 2, size / 2), bound, res))
  cell = 2 * bound / res
  centres = np.asarray(occupancy.cell_centres(res, bound))
  # Distance from the origin to each cell (a box of half-size cell/2 around its centre).
  nearest = np.linalg.norm(np.maximum(np.abs(centres) - cell / 2, 0.0), axis=-1)
  touched = nearest < ball
  assert hull[touched].min() == 1.0  # conservative: no cell the sphere enters is carved
  assert hull[nearest > 0.8].max() == 0.0  # 30 views rule out everything well outside
  assert 0.05 < hull.mean() < 0.3  # the sphere fills 6.5% of the box


def test_masks_never_carve():
  """A transient mask means unknown, not empty: a view masked whole carves as if absent, and
  masked blobs only ever keep more cells."""
  size, focal, ball, bound, res = 32, 40.0, 0.5, 1.0, 16
  poses = _views(12)
  accs = _sphere_masks(poses, size, focal, ball)
  intrinsics = (focal, focal, size / 2, size / 2)
  masks = np.ones_like(accs)
  masks[0] = 0.0
  without_view_0 = visual_hull.carve(accs[1:], poses[1:], intrinsics, bound, res)
  np.testing.assert_array_equal(
      visual_hull.carve(accs, poses, intrinsics, bound, res, masks=masks), without_view_0)
  blobs = (np.random.default_rng(0).random(accs.shape) > 0.9).astype(np.float32)
  plain = np.asarray(visual_hull.carve(accs, poses, intrinsics, bound, res))
  masked = np.asarray(visual_hull.carve(accs, poses, intrinsics, bound, res, masks=1 - blobs))
  assert (masked >= plain).all() and masked.sum() > plain.sum()


def test_carving_keeps_everything_when_a_camera_is_inside_the_box():
  poses = _views(5, radius=1.2)
  hull = visual_hull.carve(np.zeros((5, 16, 16), np.float32), poses, (20.0, 20.0, 8.0, 8.0),
                           1.0, 8)
  assert float(jnp.min(hull)) == 1.0


def test_a_subjects_vote_keeps_what_passers_by_hide_and_carves_around_it():
  size, focal, ball, bound, res = 48, 60.0, 0.5, 1.0, 24
  poses = _views(30)
  masks = _sphere_masks(poses, size, focal, ball)
  masks[::4, :, : size // 2] = 0.0  # a passer-by hides the subject's left in 8 photos of 30
  intrinsics = (focal, focal, size / 2, size / 2)
  cameras = Cameras.shared(len(poses), size, size, intrinsics)
  hull = visual_hull.carve_vote(masks, poses, cameras, bound, res, vote=0.6)
  centres = np.asarray(occupancy.cell_centres(res, bound))
  cell = 2 * bound / res
  nearest = np.linalg.norm(np.maximum(np.abs(centres) - cell / 2, 0.0), axis=-1)
  assert hull.shape == (res,) * 3 and hull[nearest < ball].min() == 1.0  # none of it carved
  assert hull[nearest > 0.8].max() == 0.0  # 22 clean photos rule out what lies well outside
  # Every photo's veto (`carve`) loses part of the subject to the passers-by; the vote does not.
  strict = np.asarray(visual_hull.carve(masks, poses, intrinsics, bound, res))
  assert strict[nearest < ball].min() == 0.0
  # A vote of all the photos is the strict carving (each mask dilated alike).
  np.testing.assert_array_equal(visual_hull.carve_vote(masks, poses, cameras, bound, res, 1.0),
                                strict)


def test_the_gate_is_the_cell_lookup_inside_the_box_and_zero_outside():
  rng = np.random.default_rng(3)
  hull = (rng.random((5, 5, 5)) > 0.5).astype(np.float32)
  bound = 1.5
  points = rng.uniform(-2.0, 2.0, (500, 3)).astype(np.float32)
  got = np.asarray(visual_hull.gate(jnp.asarray(hull), jnp.asarray(points), bound))
  expected = []
  for p in points:  # the cell holding each point, by hand
    if np.any(np.abs(p) > bound):
      expected.append(0.0)
      continue
    i, j, k = (min(int((v + bound) / (2 * bound) * 5), 4) for v in p)
    expected.append(hull[i, j, k])
  np.testing.assert_array_equal(got, expected)


# 'grid' so positions reach the stand-in as they are, 'relu' so its density passes unchanged.
UNIFORM = {"model.encoding": "grid", "model.density_activation": "relu", "render.chunk": 8,
           "num_samples": 512, "data.scene_bound": 1.5, "render.march_grid": 16}


@pytest.mark.parametrize("path", ["plain", "march"])
def test_no_density_outside_the_hull_on_every_rendering_path(path):
  # Density 1 everywhere; the hull keeps the cells of x > 0 of the box ±1.5. A ray along x
  # crosses 1.5 of kept length, one along y at x = 0.7 the whole chord 3, at x = -0.7 none.
  config = small_config(UNIFORM, **{"render.march": path == "march"})
  rr = ray_renderer(config, StandInNetwork(lambda p: (jnp.ones_like(p) * 0.5,
                                                      jnp.ones(p.shape[:-1], jnp.float32))))
  hull = np.zeros((4, 4, 4), np.float32)
  hull[2:] = 1.0
  variables = {"params": {"coarse": {}}, "hull": jnp.asarray(hull),
               "hull_bound": jnp.float32(1.5)}
  origins = np.array([[-3.0, 0.1, 0.1], [0.7, -3.0, 0.1], [-0.7, -3.0, 0.1]], np.float32)
  directions = np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 1.0, 0]], np.float32)
  rays = Rays.create(origins, directions, 1.0, 5.0)
  if path == "march":
    settings = builders.image_settings(config)
    assert image_renderer.marches(rr, settings)
    out = image_renderer.make_image_renderer(rr, settings)(variables)(rays)
  else:
    out = renderer.final(jitted(rr.render)(variables, rays))
  np.testing.assert_allclose(out["acc"], [1 - np.exp(-1.5), 1 - np.exp(-3.0), 0.0], atol=1e-2)


def test_bounding_box_of_a_block_of_cells():
  hull = np.zeros((10, 10, 10), np.float32)
  hull[2:5, 3:4, 6:10] = 1.0
  box = visual_hull.bounding_box(hull, bound=1.0, margin=1)
  # Cells are 0.2 wide from -1: kept x cells 2..4 -> [-0.6, 0.0], grown by one cell each side.
  np.testing.assert_allclose(box, [[-0.8, -0.6, 0.0], [0.2, 0.0, 1.0]], atol=1e-6)
  np.testing.assert_allclose(visual_hull.bounding_box(hull * 0, 1.0), [[-1] * 3, [1] * 3])


def test_trilinear_on_a_non_cubic_grid_matches_brute_force():
  rng = np.random.default_rng(1)
  g = rng.standard_normal((3, 7, 5, 2)).astype(np.float32)
  u = rng.random((40, 3)).astype(np.float32)
  u[0], u[1] = [1.0, 1.0, 1.0], [0.5, 1 / 6, 0.25]  # a corner and a lattice point
  got = np.asarray(grid.trilinear(jnp.asarray(g), jnp.asarray(u)))
  np.testing.assert_allclose(got, np.stack([trilinear_brute(g, p) for p in u]), atol=1e-5)
  np.testing.assert_allclose(got[1], g[1, 1, 1], atol=1e-5)


def test_axis_resolutions_keep_cells_cubic():
  box = ([-0.5, -1.0, 0.0], [0.5, 1.0, 0.5])  # sides 1, 2, 0.5
  assert grid.axis_resolutions(129, box) == (65, 129, 33)  # 64, 128, 32 cells of 1/64
  assert grid.axis_resolutions(3, box) == (2, 3, 2)  # never fewer than 2 points


def test_axis_resolutions_with_long_cells_along_z():
  box = ([-0.5, -1.0, 0.0], [0.5, 1.0, 0.5])  # sides 1, 2, 0.5
  # z cells 4x as long as x and y's: 64, 128 cells of 1/64 and 8 cells of 1/16.
  assert grid.axis_resolutions(129, box, (1.0, 1.0, 4.0)) == (65, 129, 9)
  # z cells 1/16 as long: z has the most cells (0.5 / (1/16 of x's cells)) and gets 129 points.
  assert grid.axis_resolutions(129, box, (1.0, 1.0, 1 / 16)) == (17, 33, 129)


def test_a_grid_field_with_long_cells_along_z_has_fewer_lattice_points_there():
  config = small_config(TINY_GRID, base="fast", **{"model.grid_cell_aspect": (1.0, 1.0, 4.0)})
  params = builders.make_ray_renderer(config).init(jax.random.PRNGKey(0))["params"]["coarse"]
  assert params["grid_16"].shape == (16, 16, 5, 4)  # 15 cells of x's side along z are 3.75
  assert model_signature(config)["grid_cell_aspect"] == [1.0, 1.0, 4.0]
  assert "grid_cell_aspect" not in model_signature(small_config(base="fast"))


def test_grid_field_over_a_box_is_empty_outside_it():
  space = grid.Space(box=(-0.5, -1.0, 0.0, 0.5, 1.0, 0.5))
  encoding = grid.DenseGrid(grid.Settings(resolutions=(8,), features=2), space)
  net = lattice.LatticeHead(encoding, NetworkSettings())
  points = jnp.array([[0.0, 0.0, 0.25], [0.6, 0.0, 0.25], [0.0, 0.0, -0.1]])
  params = net.init(jax.random.PRNGKey(0), points)
  assert params["params"]["grid_8"].shape == (5, 8, 3, 2)
  _, raw_sigma = net.apply(params, points)
  assert raw_sigma[0] > -1e4 and raw_sigma[1] == -1e5 and raw_sigma[2] == -1e5


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_a_run_with_the_visual_hull_samples_only_inside_it():
  # As many slots as candidates: each slot is one candidate, sampled where its cell was looked
  # up (occupancy.py), so every valid sample must lie in a cell of the hull.
  config = small_config({"data.visual_hull": True, "train.max_steps": 2,
                         "occupancy.update_every": 1, "occupancy.candidates": 32,
                         "num_samples": 32}, base="scenes/detail",
                        **{"data.image_size": 24, "data.num_views": 12,
                           "occupancy.resolution": 16, "model.grid.resolutions": (8, 16)})
  exp = experiment.setup(config)
  hull, hull_bound = exp.hull
  hull = np.asarray(hull)
  assert hull_bound == exp.config.data.scene_bound and hull.shape == (16, 16, 16) and 0.0 < hull.mean() < 1.0
  box = np.reshape(exp.config.model.grid_box, (2, 3))
  assert np.all(box[0] > -exp.config.data.scene_bound - 1e-6) and np.all(box[1] > box[0])
  state = init_state(exp)
  np.testing.assert_array_equal(np.asarray(state.buffers["occupancy"]), hull)
  step = builders.make_train_step(exp)
  data = builders.make_train_data(exp)
  for _ in range(2):  # step 0 refreshes the grid from the field (update_every = 1)
    state, _ = step(state, data, jax.random.PRNGKey(0))
  grid_after = np.asarray(state.buffers["occupancy"])
  assert grid_after.max() > 0 and np.all(grid_after[hull == 0] == 0)
  ray_batch = exp.rays(exp.train_ds.poses[0])
  samples = jitted(exp.renderer.sampler.place)(ray_batch, None, state.buffers["occupancy"])
  points = np.asarray(jitted(placement.points)(ray_batch, samples.distances))[
      np.asarray(samples.valid)]
  assert len(points) > 0
  in_hull = jitted(occupancy.lookup, bound=exp.config.data.scene_bound)(
      jnp.asarray(hull > 0), jnp.asarray(points))
  assert bool(jnp.all(in_hull))


def test_a_run_on_a_subjects_masks_carves_their_vote_whatever_the_box():
  # data.subject on and masks that keep the subject: the hull is the vote (from_data.HULL_VOTE)
  # of the moved photos on the cells of twice the scene box, contracted or not; without
  # data.subject the masks are a passer-by's and carve nothing.
  size, focal, ball = 48, 60.0, 0.5
  poses = _views(30)
  masks = _sphere_masks(poses, size, focal, ball)
  dataset = Dataset(np.zeros((30, size, size, 3), np.float32), poses,
                    (focal, focal, size / 2, size / 2), near=1.0, far=8.0, masks=masks)
  config = small_config(base="capture", **{"data.visual_hull": True, "data.subject": "masks",
                                           "data.scene_bound": 0.8, "data.contraction": "linf"})
  out, (hull, bound) = from_data.with_visual_hull(config, dataset)
  cameras = Cameras.shared(30, size, size, (focal, focal, size / 2, size / 2))
  assert bound == 1.6 and hull.shape == (from_data.SUBJECT_HULL_CELLS,) * 3
  np.testing.assert_array_equal(hull, visual_hull.carve_vote(
      masks, poses, cameras, 1.6, from_data.SUBJECT_HULL_CELLS, from_data.HULL_VOTE,
      from_data.pixel_center(config, dataset)))
  assert out is config and 0.02 < float(jnp.mean(hull)) < 0.1  # the ball: 3.2% of the box
  config.data.subject = ""
  assert from_data.with_visual_hull(config, dataset)[1] is None


def test_one_vote_counts_each_photo_through_its_own_camera():
  # mask_votes (the vote of the subject's box, its hull and the photos' zoom) against a vote
  # written here: each point projected through each photo's own size and intrinsics, its mask
  # read over the square window of the point's radius, pixel by pixel.
  rng = np.random.default_rng(7)
  poses = _views(6).astype(np.float64)
  cameras = [(h, w, (f, 1.1 * f, w / 2 + 1.5, h / 2 - 2.0))
             for h, w, f in [(20, 30, 25.0), (24, 24, 40.0), (30, 20, 30.0)] * 2]
  masks = [(rng.random((h, w)) > 0.8).astype(np.float32) for h, w, _ in cameras]
  points = rng.uniform(-1.5, 1.5, (400, 3))
  radius = lambda k, depth: None if k == 5 else (np.arange(len(depth)) + k) % 3  # 5 abstains
  seen, kept = visual_hull.mask_votes(masks, poses, Cameras.stack(cameras), points, radius, 0.5)
  want_seen, want_kept = np.zeros(len(points)), np.zeros(len(points))
  for k, (pose, (h, w, (fx, fy, cx, cy)), mask) in enumerate(zip(poses, cameras, masks)):
    if k == 5:
      continue
    for m, point in enumerate(points):
      x, y, z = (point - pose[:3, 3]) @ pose[:3, :3]
      i = int(np.floor(cx + fx * x / -z - 0.5 + 0.5))  # the pixel whose centre ray is nearest
      j = int(np.floor(cy - fy * y / -z - 0.5 + 0.5))
      if -z <= 0 or not (0 <= i < w and 0 <= j < h):
        continue
      r = (m + k) % 3
      want_seen[m] += 1
      want_kept[m] += mask[max(j - r, 0):j + r + 1, max(i - r, 0):i + r + 1].any()
  np.testing.assert_array_equal(seen, want_seen)
  np.testing.assert_array_equal(kept, want_kept)
  assert 0 < kept.sum() < seen.sum()


def test_a_window_read_from_the_summed_table_is_the_dilated_mask():
  rng = np.random.default_rng(8)
  mask = (rng.random((17, 23)) > 0.93).astype(np.float32)
  rows, columns = np.meshgrid(np.arange(17), np.arange(23), indexing="ij")
  for radius in (0, 1, 3, 30):
    np.testing.assert_array_equal(
        visual_hull.kept_within(mask, rows.reshape(-1), columns.reshape(-1), radius),
        np.asarray(visual_hull.dilated(mask, radius)).reshape(-1) > 0)


def test_a_footprint_covers_the_ball_it_stands_for():
  # A ball of radius 0.3 straight ahead at depth z spans f tan(asin(0.3 / z)) pixels from its
  # centre's: the footprint holds that, within 10% and two pixels from 10 radii away, and is the
  # whole image from within the ball.
  camera, reach = (40, 60, (50.0, 45.0, 30.0, 20.0)), 0.3
  depth = np.array([0.1, 0.3, 0.5, 1.0, 3.0, 4.0, 20.0])
  got = visual_hull.footprint_radius(reach, camera, depth)
  spans = 50.0 * np.tan(np.arcsin(np.minimum(reach / depth, 1.0)))
  ahead, far = depth > reach, depth >= 10 * reach
  assert np.all(got[ahead] >= spans[ahead]) and np.all(got <= 60)
  assert np.all(got[far] <= 1.1 * spans[far] + 2)
  np.testing.assert_array_equal(got[~ahead], 60)
