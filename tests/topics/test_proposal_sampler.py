"""The proposal sampler (samplers/proposal.py: ProposalSampler, Interlevel) and the seams it
plugs into: a sampler's parameters, density functions, extras and loss terms.

The interlevel term is checked against the O(S·M) brute force of tests/samplers/test_proposal.py, the
bound property with a proposal whose density is the NeRF's (constant along each ray, where the
quadrature is exact), and the built-in sampler's path against `place` as it was.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.cameras.rays import Rays
from nerf_jax.render import image_renderer
from nerf_jax.run import builders, experiment, train_lib
from nerf_jax.run.signature import model_signature
from nerf_jax.samplers import placement, proposal, spacing
from nerf_jax.samplers.occupancy import OccupancySettings
from nerf_jax.train import losses
from nerf_jax.volume import quadrature
from nerf_jax.train.losses import colour as colour_loss
from tests.helpers import params_equal, restored_variables
from tests.helpers import jitted, small_config
from tests.helpers import loss_ref
from tests import helpers

pytestmark = pytest.mark.usefixtures("debug_nans")  # conftest.py: a NaN anywhere raises

BOUND = 4.0  # the scene box's half-size (the inner box with contraction)
# configs/scenes/garden.py with the proposal sampler at tiny sizes: two levels of 16 and 8
# samples, 8 NeRF samples, hash grids of 2 levels up to 32 in 2^10 rows.
TINY = {"sampler": "proposal", "num_samples": 8, "proposal.num_samples": (16, 8),
        "proposal.levels": 2, "proposal.log2_size": 10, "proposal.base_resolution": 8,
        "proposal.max_resolution": (16, 32), "model.grid.resolutions": (8, 16),
        "data.scene_bound": BOUND}


def _config(contraction="", **fields):
  return small_config({**TINY, "data.contraction": contraction, **fields},
                      base="scenes/garden")


def _rays(count=24):
  """Rays [count] of one camera 6 units out, some through the box, some past it: near 0.5,
  far 40 (the bounded sampler cuts them to the box; contraction samples out to 1e10)."""
  return Rays.create(*helpers.view_rays(6, 4, 3.0, 30.0, -20.0, 6.0, count), 0.5, 40.0)


@pytest.fixture(scope="module", params=["", "linf"], ids=["bounded", "contracted"])
def rendered(request):
  """(ray renderer, variables, rays, render outputs with a key) of the tiny proposal config."""
  rr = builders.make_ray_renderer(_config(request.param))
  variables = rr.init(jax.random.PRNGKey(0))
  rays = _rays()
  outputs = jax.jit(lambda v, r, k: rr.render(v, r, k))(variables, rays, jax.random.PRNGKey(1))
  return rr, variables, rays, outputs


# The seams: what the built-in sampler does is unchanged.

@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_builtin_sampler_generates_what_it_placed_and_brings_nothing():
  rays, key = _rays(), jax.random.PRNGKey(2)
  plain = placement.Sampler(16, BOUND)
  oc = OccupancySettings(resolution=8, candidates=32)
  occupied = placement.Sampler(8, BOUND, occupancy=oc)
  grid = jnp.ones((8, 8, 8), jnp.float32)
  for rs, variables in ((plain, {}), (occupied, {"occupancy": grid})):
    samples, extras = jitted(rs.generate)(rays, key, {"params": {}, **variables})
    want = jitted(rs.place)(rays, key, variables.get("occupancy"))
    assert extras == {} and samples.gapped == want.gapped
    for a, b in zip(jax.tree_util.tree_leaves(samples), jax.tree_util.tree_leaves(want)):
      np.testing.assert_array_equal(a, b)
    assert rs.init(key) == {} and rs.signature() == {} and rs.loss_terms() == []
  assert plain.marchable and not occupied.marchable


def test_builtin_renderer_has_no_sampler_parameters_outputs_or_terms():
  config = small_config()
  rr = builders.make_ray_renderer(config)
  assert type(rr.sampler) is placement.Sampler  # pylint: disable=unidiomatic-typecheck
  variables = rr.init(jax.random.PRNGKey(0))
  assert sorted(variables["params"]) == sorted(rr.networks)
  assert "sampler" not in rr.render(variables, _rays(4))
  assert not any(key.startswith(("sampler", "proposal"))
                 for key in model_signature(config))
  assert [type(t) for t in builders.loss_terms(config, rr)] == [colour_loss.Colour]


# The proposal sampler.

def test_sampler_owns_its_levels_parameters_signature_and_term():
  config = _config("linf")
  rr = builders.make_ray_renderer(config)
  assert isinstance(rr.sampler, proposal.ProposalSampler) and not rr.sampler.marchable
  assert not image_renderer.marches(rr, builders.image_settings(config))
  variables = rr.init(jax.random.PRNGKey(0))
  assert sorted(variables["params"]) == ["coarse", "proposal_0", "proposal_1"]
  # The NeRF's parameters are those of the built-in sampler's renderer: same key, same values.
  plain = builders.make_ray_renderer(_config("linf", sampler=""))
  assert params_equal(variables["params"]["coarse"],
                      plain.init(jax.random.PRNGKey(0))["params"]["coarse"])
  signature = model_signature(config)
  assert signature["sampler"] == "proposal" and signature["proposal_max_resolution"] == [16, 32]
  terms = builders.loss_terms(config, rr)
  assert isinstance(terms[-1], proposal.Interlevel) and terms[-1].weight == 1.0


def test_samples_are_sorted_inside_the_bounds_and_finite(rendered):
  rr, variables, rays, _ = rendered
  near, far = rr.sampler.bounds(rays)
  far = jnp.minimum(far, spacing.MAX_FAR)  # contraction: far = inf, sampled out to 1e10
  for key in (None, jax.random.PRNGKey(3)):
    samples, extras = jax.jit(rr.sampler.generate)(rays, key, variables)
    levels = extras["proposals"]
    assert [lv["t"].shape[-1] - 1 for lv in levels] == [16, 8]
    assert samples.t.shape == (24, 9) and samples.distances.shape == (24, 8)
    for t in [samples.t] + [lv["t"] for lv in levels]:
      t = np.asarray(t)
      assert np.all(np.isfinite(t)) and np.all(np.diff(t, axis=-1) >= 0)
      np.testing.assert_array_equal(t[:, 0], near)
      np.testing.assert_array_equal(t[:, -1], far)
    d = np.asarray(samples.distances)
    assert np.all((d >= samples.t[:, :-1]) & (d <= samples.t[:, 1:]))
    for lv in levels:
      w = np.asarray(lv["weights"])
      assert np.all(w >= 0) and np.all(np.sum(w, -1) <= 1 + 1e-5)
  if rr.sampler.contraction:
    assert np.all(far == spacing.MAX_FAR)


def test_the_shipped_config_has_one_dense_lattice_level_and_places_finite_samples():
  config = small_config({"data.scene_bound": BOUND}, base="scenes/garden_proposal")
  rr = builders.make_ray_renderer(config)
  variables = rr.init(jax.random.PRNGKey(0))
  level = variables["params"]["proposal_0"]
  assert sorted(variables["params"]) == ["coarse", "proposal_0"]
  assert level["lattice_16"].shape == (16, 16, 16, 2)
  samples, extras = jax.jit(rr.sampler.generate)(_rays(), jax.random.PRNGKey(3), variables)
  t = np.asarray(samples.t)
  assert t.shape == (24, 33) and extras["proposals"][0]["t"].shape == (24, 65)
  assert np.all(np.isfinite(t)) and np.all(np.diff(t, axis=-1) >= 0)
  assert np.all(t[:, -1] == spacing.MAX_FAR)


def test_interlevel_term_matches_the_brute_force(rendered):
  rr, variables, rays, outputs = rendered
  inputs = losses.LossInputs(outputs, jnp.zeros((24, 3)), rays, variables["params"])
  last = outputs["coarse"]
  want = sum(np.mean(loss_ref(last["t"], last["weights"], lv["t"], lv["weights"]))
             for lv in outputs["sampler"]["proposals"])
  value, stats = proposal.Interlevel(2.0)(inputs)
  # As tests/samplers/test_proposal.py: outer exact to ~1e-6, d(term)/d(outer) <= 2, 8 intervals.
  np.testing.assert_allclose(stats["unweighted"], want, rtol=1e-5, atol=2e-6 * 8)
  np.testing.assert_allclose(value, 2.0 * stats["unweighted"], rtol=1e-6)
  assert want > 1e-4  # untrained levels do not bound the NeRF


@pytest.mark.parametrize("contraction", ["", "linf"])
def test_a_proposal_with_the_nerfs_density_bounds_its_weights(contraction):
  """A step function along each ray, constant (the quadrature is exact): per ray a density of
  0 (empty), 0.05 (thin), 1 or 1e3 (opaque) per unit length. Every level with the NeRF's own
  density bounds the NeRF's weights, and the interlevel loss is 0."""
  rr = builders.make_ray_renderer(_config(contraction))
  rays = _rays()
  per_ray = jnp.asarray(np.resize([0.0, 0.05, 1.0, 1e3], 24), jnp.float32)
  density = lambda points: jnp.broadcast_to(per_ray[:, None], points.shape[:-1])

  @jax.jit
  def place(key):
    samples, extras = rr.sampler.generate_from(rays, [density, density], key)
    sigma = placement.per_unit_t(density(placement.points(rays, samples.distances)), rays)
    return samples.t, quadrature.compute_weights(sigma, samples.t)[0], extras["proposals"]

  for key in (None, jax.random.PRNGKey(4)):
    t, w, levels = place(key)
    for lv in levels:
      bound = proposal.outer(t, lv["t"], lv["weights"])
      assert np.all(np.asarray(bound) >= np.asarray(w) - 1e-5)
      np.testing.assert_allclose(proposal.interlevel_loss(t, w, lv["t"], lv["weights"]), 0.0,
                                 atol=1e-5)
    assert np.max(w) > 0.5  # the opaque rays end in one interval


@pytest.mark.slow  # trains or renders for more than ~10 s on 2 cores
def test_photometric_loss_trains_the_nerf_and_interlevel_the_proposals_only(rendered):
  rr, variables, rays, _ = rendered
  target = jax.random.uniform(jax.random.PRNGKey(5), (24, 3))

  def grads(term):
    def loss(params):
      outs = rr.render({**variables, "params": params}, rays, jax.random.PRNGKey(1))
      return term(losses.LossInputs(outs, target, rays, params))[0]
    return jax.jit(jax.grad(loss))(variables["params"])

  colour, interlevel = grads(colour_loss.Colour()), grads(proposal.Interlevel())
  nonzero = lambda tree: any(np.any(np.asarray(g) != 0) for g in jax.tree_util.tree_leaves(tree))
  for name in ("proposal_0", "proposal_1"):
    assert not nonzero(colour[name]) and nonzero(interlevel[name]), name
  assert nonzero(colour["coarse"]) and not nonzero(interlevel["coarse"])


def test_the_resample_setting_reaches_the_levels():
  """proposal.resample = 'jittered_grid' (mip-NeRF 360's draws): without a key the samples are
  the default's bit for bit (the deterministic quantiles); with a key they are not the sorted
  uniforms' of the same key."""
  samplers = [builders.make_ray_renderer(_config("linf", **fields)).sampler
              for fields in ({}, {"proposal.resample": "jittered_grid"})]
  assert [s.settings.resample for s in samplers] == ["sorted_uniform", "jittered_grid"]
  rays = _rays()
  density = lambda points: jnp.full(points.shape[:-1], 0.3, jnp.float32)
  place = jax.jit(lambda key, s: s.generate_from(rays, [density, density], key)[0].t,
                  static_argnums=1)
  np.testing.assert_array_equal(place(None, samplers[0]), place(None, samplers[1]))
  key = jax.random.PRNGKey(4)
  default, grid = place(key, samplers[0]), place(key, samplers[1])
  assert np.all(np.diff(np.asarray(grid), axis=-1) >= 0) and not np.allclose(default, grid)


@pytest.mark.parametrize("fields, match", [
    ({"sampler": "nope"}, "config.sampler must be one of placement, proposal"),
    ({"proposal.max_resolution": (64,)}, "config.proposal.max_resolution"),
    ({"proposal.num_samples": (32, 0)}, "config.proposal.num_samples"),
    ({"proposal.padding": -1.0}, "config.proposal.padding"),
    ({"proposal.field": "mlp"}, "config.proposal.field"),
    ({"proposal.resample": "stratified"}, "config.proposal.resample"),
    ({"occupancy.enabled": True}, "config.occupancy.enabled"),
    ({"num_fine_samples": 16}, "config.num_fine_samples"),
    ({"data.scene_bound": 0.0}, "config.data.scene_bound"),
])
def test_settings_that_cannot_work_are_one_line_naming_the_field(fields, match):
  with pytest.raises(ValueError) as info:
    builders.make_ray_renderer(_config(**fields))
  assert match in str(info.value) and "\n" not in str(info.value)


def test_unknown_setting_in_the_section_is_named():
  with pytest.raises(ValueError, match="config.proposal has no setting 'level'"):
    proposal.settings_from({"level": 3})


@pytest.mark.slow
def test_training_lowers_the_loss_and_the_checkpoint_restores(tmp_path):
  workdir = str(tmp_path / "run")
  config = _config("linf", **{"data.num_views": 6, "data.image_size": 16,
                              "data.holdout_from": 5, "train.max_steps": 40,
                              "train.batch_rays": 128, "train.log_every": 5,
                              "train.checkpoint_every": 40})
  result = train_lib.train_and_evaluate(config, workdir)
  assert result["steps"] == 40 and np.isfinite(result["psnr"])
  records = [json.loads(line) for line in open(f"{workdir}/metrics.jsonl")]
  logged = [r for r in records if "interlevel/unweighted" in r]
  assert len(logged) == 8  # the term's stat is logged with the others, under its name
  assert logged[-1]["loss"] < logged[0]["loss"] and logged[-1]["interlevel/unweighted"] < logged[
      0]["interlevel/unweighted"]
  exp, state = experiment.restore(workdir)
  assert sorted(state.params) == ["coarse", "proposal_0", "proposal_1"]
  again = builders.make_evaluator(exp)(restored_variables(workdir))
  assert again["per_view"] == json.loads(open(f"{workdir}/metrics.json").read())["per_view"]
  # A checkpoint of the proposal sampler does not restore under the built-in one.
  assert model_signature(config) != model_signature(
      _config("linf", sampler=""))
