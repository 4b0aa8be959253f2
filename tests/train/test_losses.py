"""Tests of nerf_jax.train.losses: each built-in term against a brute-force reference written
here, `total`'s namespaced stats and its clash error, and the registry of terms the entry layer
builds from config.loss (run/builders.loss_terms)."""

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from nerf_jax.backend import components as component_lib
from nerf_jax.cameras import rays as rays_lib
from nerf_jax.run import builders, config_lib
from nerf_jax.samplers import placement, proposal
from nerf_jax.train import losses
from nerf_jax.train.losses import colour, distortion, pose_prior, total_variation
from tests.helpers import small_config

B = 6  # rays per batch
RNG = np.random.default_rng(0)
RGB = {name: RNG.uniform(size=(B, 3)).astype(np.float32) for name in ("coarse", "fine")}
TARGET = RNG.uniform(size=(B, 3)).astype(np.float32)
COMPLETE = np.array([True, False, True, True, False, True])
VALID = np.array([4, 9, 0, 3, 8, 2], np.int32)


def _colour_inputs(passes, budget=False):
  outputs = {name: {"rgb": jnp.asarray(RGB[name])} for name in passes}
  if budget:  # a sample budget's outputs (render/renderer.py): on the coarse pass, both
    outputs["coarse"].update(complete=jnp.asarray(COMPLETE), valid_samples=jnp.asarray(VALID))
  return losses.LossInputs(outputs, jnp.asarray(TARGET), None, {})


def _pass_error_ref(rgb, keep, delta):
  """The mean over kept rays and channels of the squared error (delta 0) or Huber's loss, one
  element at a time."""
  values = []
  for ray in range(B):
    if not keep[ray]:
      continue
    for ch in range(3):
      e = float(rgb[ray, ch]) - float(TARGET[ray, ch])
      if delta <= 0:
        values.append(e * e)
      else:
        values.append(e * e / 2 if abs(e) <= delta else delta * (abs(e) - delta / 2))
  return sum(values) / len(values)


@pytest.mark.parametrize("passes", [("coarse",), ("coarse", "fine")])
@pytest.mark.parametrize("delta", [0.0, 0.1])
@pytest.mark.parametrize("budget", [False, True])
def test_colour_is_the_final_pass_error_plus_the_weighted_coarse_one(passes, delta, budget):
  keep = COMPLETE if budget else np.ones(B, bool)
  loss, stats = colour.Colour(coarse_weight=0.3, huber_delta=delta)(
      _colour_inputs(passes, budget))
  final = passes[-1]
  want = _pass_error_ref(RGB[final], keep, delta)
  if final == "fine":
    want += 0.3 * _pass_error_ref(RGB["coarse"], keep, delta)
  np.testing.assert_allclose(loss, want, rtol=1e-5)
  # PSNR of the final pass, from its squared error whatever the loss.
  np.testing.assert_allclose(stats["psnr"], -10 * np.log10(_pass_error_ref(RGB[final], keep, 0)),
                             rtol=1e-5)
  if budget:  # the rays it held whole, and the valid samples all drawn rays asked for
    assert set(stats) == {"psnr", "rays_in_loss", "samples_wanted"}
    assert int(stats["rays_in_loss"]) == 4 and int(stats["samples_wanted"]) == 26
  else:
    assert set(stats) == {"psnr"}


def test_colour_logs_the_share_of_masked_rays():
  mask = np.array([1, 0, 1, 1, 0, 0], np.float32)  # three of six rays masked
  inputs = _colour_inputs(("coarse",)).replace(weight=jnp.asarray(mask),
                                               mask=jnp.asarray(mask))
  loss, stats = colour.Colour()(inputs)
  assert set(stats) == {"psnr", "masked_share"}
  np.testing.assert_allclose(stats["masked_share"], sum(m == 0 for m in mask) / B, rtol=1e-6)
  np.testing.assert_allclose(loss, _pass_error_ref(RGB["coarse"], mask > 0, 0.0), rtol=1e-5)


def test_colour_with_no_whole_ray_is_finite():
  inputs = _colour_inputs(("coarse",), budget=True)
  none = jnp.zeros(B, bool)
  inputs = inputs.replace(outputs={"coarse": {**inputs.outputs["coarse"], "complete": none}})
  loss, stats = colour.Colour()(inputs)
  assert float(loss) == 0.0 and int(stats["rays_in_loss"]) == 0


LOSSMULT = np.array([1.0, 4.0, 16.0, 1.0, 64.0, 4.0], np.float32)  # each ray's image's lossmult


@pytest.mark.parametrize("passes", [("coarse",), ("coarse", "fine")])
@pytest.mark.parametrize("delta", [0.0, 0.1])
@pytest.mark.parametrize("budget", [False, True])
def test_a_per_ray_weight_makes_the_colour_loss_a_weighted_mean(passes, delta, budget):
  """mip-NeRF's lossmult: sum(w · e) / sum(w) over the kept rays and channels, by hand."""
  keep = COMPLETE if budget else np.ones(B, bool)

  def ref(rgb):
    num = den = 0.0
    for ray in range(B):
      for ch in range(3):
        e = float(rgb[ray, ch]) - float(TARGET[ray, ch])
        value = e * e if delta <= 0 else (e * e / 2 if abs(e) <= delta else
                                          delta * (abs(e) - delta / 2))
        num += keep[ray] * LOSSMULT[ray] * value
        den += keep[ray] * LOSSMULT[ray]
    return num / den

  inputs = _colour_inputs(passes, budget).replace(weight=jnp.asarray(LOSSMULT))
  loss, _ = colour.Colour(coarse_weight=0.3, huber_delta=delta)(inputs)
  want = ref(RGB[passes[-1]]) + (0.3 * ref(RGB["coarse"]) if len(passes) == 2 else 0.0)
  np.testing.assert_allclose(loss, want, rtol=1e-5)


def test_equal_weights_give_the_unweighted_loss():
  inputs = _colour_inputs(("coarse", "fine"))
  plain = colour.Colour()(inputs)[0]
  weighted = colour.Colour()(inputs.replace(weight=jnp.full(B, 4.0)))[0]
  np.testing.assert_allclose(weighted, plain, rtol=1e-6)


def _distortion_ref(s, w):
  """mip-NeRF 360's distortion of one ray as its double sum: edges s [S + 1], weights w [S]."""
  mids = [(s[i] + s[i + 1]) / 2 for i in range(len(w))]
  between = sum(w[i] * w[j] * abs(mids[i] - mids[j])
                for i in range(len(w)) for j in range(len(w)))
  within = sum(w[i] ** 2 * (s[i + 1] - s[i]) for i in range(len(w))) / 3
  return between + within


def _ray_outputs(num, near, far):
  """Rays [B] between near and far, and a pass's sorted edges t [B, num + 1] and weights."""
  origins = RNG.normal(size=(B, 3)).astype(np.float32)
  directions = RNG.normal(size=(B, 3)).astype(np.float32)
  t = np.sort(RNG.uniform(near, far, (B, num + 1)), axis=-1).astype(np.float32)
  w = RNG.uniform(0.0, 0.2, (B, num)).astype(np.float32)
  return rays_lib.Rays.create(origins, directions, near, far), t, w


def test_distortion_is_the_weighted_mean_double_sum_of_the_final_pass_in_unit_distance():
  rays, t, w = _ray_outputs(7, 2.0, 6.0)
  outputs = {"coarse": {"t": jnp.zeros_like(t), "weights": jnp.ones_like(w)},  # not the final
             "fine": {"t": jnp.asarray(t), "weights": jnp.asarray(w)}}
  term = distortion.Distortion(0.25, placement.Sampler(7, scene_bound=3.0).unit_distance)
  loss, stats = term(losses.LossInputs(outputs, jnp.zeros((B, 3)), rays, {}))
  s = (t.astype(np.float64) - 2.0) / 4.0  # a bounded scene's unit distance: (t - near)/(far - near)
  want = 0.25 * np.mean([_distortion_ref(s[r], w[r].astype(np.float64)) for r in range(B)])
  np.testing.assert_allclose(loss, want, rtol=1e-5)
  assert stats == {}


def _tv_ref(table, axes):
  """Total variation of `table` [R_1..R_k, C] over its first `axes` axes: per axis, the mean of
  the squared differences of neighbours, summed, one pair at a time."""
  table = np.asarray(table, np.float64)
  out = 0.0
  for axis in range(axes):
    diffs = []
    for index in itertools.product(*(range(n) for n in table.shape)):
      if index[axis] + 1 < table.shape[axis]:
        after = index[:axis] + (index[axis] + 1,) + index[axis + 1:]
        diffs.append((table[after] - table[index]) ** 2)
    out += np.mean(diffs) if diffs else 0.0
  return out


def test_total_variation_sums_each_lattice_tables_neighbour_differences():
  params = {"coarse": {"grid_4": jnp.asarray(RNG.normal(size=(4, 3, 5, 2)), jnp.float32),
                       "plane_0": jnp.asarray(RNG.normal(size=(3, 4, 2)), jnp.float32),
                       "hidden": {"kernel": jnp.ones((4, 4))}},  # not a table: no term
            "poses": jnp.ones((2, 6))}
  term = total_variation.TotalVariation(0.5, (("grid_", 3), ("plane_", 2)))
  loss, stats = term(losses.LossInputs({}, None, None, params))
  want = 0.5 * (_tv_ref(params["coarse"]["grid_4"], 3) + _tv_ref(params["coarse"]["plane_0"], 2))
  np.testing.assert_allclose(loss, want, rtol=1e-5)
  assert stats == {}


def test_pose_prior_is_the_weighted_mean_squared_correction():
  poses = RNG.normal(size=(4, 6)).astype(np.float32)
  loss, stats = pose_prior.PosePrior(3.0)(
      losses.LossInputs({}, None, None, {"poses": jnp.asarray(poses)}))
  want = 3.0 * sum(sum(float(v) ** 2 for v in camera) for camera in poses) / len(poses)
  np.testing.assert_allclose(loss, want, rtol=1e-5)
  assert stats == {}


# --- total: the sum in order, namespaced stats, a clash is an error -------------------------

def test_total_adds_the_terms_and_namespaces_their_stats():
  inputs = _colour_inputs(("coarse",), budget=True)
  inputs = inputs.replace(params={"poses": jnp.ones((2, 6))})
  terms = [colour.Colour(), pose_prior.PosePrior(0.5)]
  loss, stats = losses.total(terms, inputs)
  parts = [term(inputs)[0] for term in terms]
  assert float(loss) == float(parts[0] + parts[1])  # in the terms' order
  assert set(stats) == {"loss", "colour/psnr", "colour/rays_in_loss", "colour/samples_wanted"}
  assert float(stats["loss"]) == float(loss)
  assert float(stats["colour/psnr"]) == float(terms[0](inputs)[1]["psnr"])


def test_two_terms_logging_one_name_are_an_error_not_an_overwrite():
  inputs = _colour_inputs(("coarse",))
  with pytest.raises(ValueError, match=r"clash.*'colour'.*'psnr' \(colour/psnr\)"):
    losses.total([colour.Colour(), colour.Colour(huber_delta=0.1)], inputs)
  # Two terms of one name that log nothing, or different stats, do not clash.
  both = [pose_prior.PosePrior(1.0), pose_prior.PosePrior(2.0)]
  loss, stats = losses.total(both, inputs.replace(params={"poses": jnp.ones((1, 6))}))
  assert float(loss) == pytest.approx(18.0) and set(stats) == {"loss"}


def test_a_term_without_a_name_is_refused():
  with pytest.raises(TypeError, match="has no name"):
    losses.total([lambda inputs: (jnp.float32(0.0), {})], _colour_inputs(("coarse",)))


def test_the_proposal_samplers_term_has_its_own_namespace():
  assert proposal.Interlevel.name == "interlevel"
  assert {c.name for c in (colour.Colour, distortion.Distortion, pose_prior.PosePrior,
                           total_variation.TotalVariation, proposal.Interlevel)} == {
      "colour", "distortion", "pose_prior", "total_variation", "interlevel"}


# --- the registry and the config ------------------------------------------------------------

def test_the_registry_finds_the_built_ins_and_names_the_field_for_an_unknown_term():
  assert losses.REGISTRY.names() == ("colour", "distortion", "pose_prior", "total_variation",
                                     "transient", "robust", "masked_empty", "depth")
  for name in losses.REGISTRY.names():
    record = losses.REGISTRY.lookup(name)
    assert record.name == name
    assert losses.REGISTRY.lookup(f"nerf_jax.train.losses.{name}") is record  # a module path
  with pytest.raises(ValueError, match="config.loss.terms must be one of colour, distortion, "
                                       "pose_prior, total_variation, transient, robust, "
                                       "masked_empty, depth or a module path, got 'l1'"):
    losses.REGISTRY.lookup("l1")
  with pytest.raises(ValueError, match="cannot import no.such_module"):
    losses.REGISTRY.lookup("no.such_module")
  with pytest.raises(ValueError, match="defines no LOSS"):
    losses.REGISTRY.lookup("nerf_jax.train.regularizers")


def test_the_default_configs_sections_are_the_terms_settings():
  config = config_lib.default()
  assert tuple(config.loss.terms) == losses.REGISTRY.names()
  for name in config.loss.terms:
    settings = losses.REGISTRY.lookup(name).settings
    assert config.loss[name].to_dict() == component_lib.section(settings)


def _terms(**fields):
  config = small_config(**fields)
  return builders.loss_terms(config, builders.make_ray_renderer(config))


def test_loss_terms_builds_the_listed_terms_in_order_and_leaves_out_those_at_weight_0():
  assert [type(t) for t in _terms()] == [colour.Colour]  # debug: pose prior needs refinement
  terms = _terms(**{"loss.distortion.weight": 0.1, "loss.pose_prior.weight": 2.0,
                    "loss.total_variation.weight": 0.5, "train.pose_refinement": True,
                    "loss.colour.coarse_weight": 0.25, "loss.colour.huber_delta": 0.1})
  assert [t.name for t in terms] == ["colour", "distortion", "pose_prior", "total_variation"]
  assert (terms[0].coarse_weight, terms[0].huber_delta) == (0.25, 0.1)
  assert [t.weight for t in terms[1:]] == [0.1, 2.0, 0.5]
  # The listed order is the order they are added in.
  reordered = _terms(**{"loss.terms": ("total_variation", "colour"),
                        "loss.total_variation.weight": 0.5})
  assert [t.name for t in reordered] == ["total_variation", "colour"]


def test_the_old_flat_fields_build_the_same_terms():
  old = small_config(**{"train.pose_refinement": True})
  for field, value in {"train.distortion_weight": 0.1, "train.pose_prior": 2.0,
                       "train.tv_weight": 0.5, "train.coarse_loss_weight": 0.25,
                       "train.huber_delta": 0.1}.items():
    section, name = field.split(".")
    old[section][name] = value  # a config file that sets the old names
  new = config_lib.upgrade(old)
  rr = builders.make_ray_renderer(new)
  want = _terms(**{"loss.distortion.weight": 0.1, "loss.pose_prior.weight": 2.0,
                   "loss.total_variation.weight": 0.5, "train.pose_refinement": True,
                   "loss.colour.coarse_weight": 0.25, "loss.colour.huber_delta": 0.1})
  got = builders.loss_terms(new, rr)
  assert [(t.name, getattr(t, "weight", None)) for t in got] == [
      (t.name, getattr(t, "weight", None)) for t in want]


@pytest.mark.parametrize("fields, match", [
    ({"loss.terms": ("colour", "nope")}, "config.loss.terms must be one of"),
    ({"loss.terms": ("distortion",)}, "must include 'colour'"),
    ({"loss.terms": ("colour", "distortion", "nerf_jax.train.losses.distortion")},
     "'distortion' is listed twice"),
    ({"loss.colour.huber_delta": -0.1}, "config.loss.colour.huber_delta=-0.1"),
    ({"loss.distortion.weight": -1.0}, "config.loss.distortion.weight=-1.0"),
    ({"loss.pose_prior.weight": -1.0}, "config.loss.pose_prior.weight=-1.0"),
    ({"loss.total_variation.weight": -1.0}, "config.loss.total_variation.weight=-1.0"),
])
def test_loss_settings_that_cannot_work_name_the_field(fields, match):
  with pytest.raises(ValueError, match=match):
    _terms(**fields)


def test_a_misspelt_or_missing_section_is_named():
  config = small_config()
  config.loss.distortion.wieght = 0.1
  with pytest.raises(ValueError, match="config.loss.distortion has no setting 'wieght'"):
    builders.loss_terms(config, builders.make_ray_renderer(config))
  config = small_config()
  del config.loss["distortion"]
  with pytest.raises(ValueError, match="config.loss.distortion is missing"):
    builders.loss_terms(config, builders.make_ray_renderer(config))


def test_the_terms_gradients_match_their_references():
  """The terms are differentiable as the references say: d(pose prior)/d(poses) = 2·w·ξ/N."""
  poses = jnp.asarray(RNG.normal(size=(3, 6)), jnp.float32)
  grad = jax.grad(lambda p: pose_prior.PosePrior(1.5)(
      losses.LossInputs({}, None, None, {"poses": p}))[0])(poses)
  np.testing.assert_allclose(grad, 2 * 1.5 * np.asarray(poses) / 3, rtol=1e-5)
