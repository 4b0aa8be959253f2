"""backend/gpu_atomics.py: which jaxlibs get LLVM's native-atomics option, how it joins
XLA_FLAGS, and that this jaxlib's XLA accepts what `apply` sets (a subprocess per case: XLA reads
XLA_FLAGS once per process)."""

import importlib.metadata
import os
import subprocess
import sys

import pytest

from nerf_jax.backend import gpu_atomics

OPTION_FLAG = "--xla_backend_extra_options=-nvptx-allow-ftz-atomics"


@pytest.mark.parametrize("version, expected", [
    ("0.4.33", False), ("0.10.1", False), ("0.10.2", True), ("0.10.9", True),
    ("0.11.0", True), ("0.11.0.dev20260701", True), ("0.11.1", False), ("0.11.2", False),
    ("1.0.0", False)])
def test_only_the_releases_with_the_cas_loop_are_affected(version, expected):
  assert gpu_atomics.affected(version) is expected


def test_a_version_without_a_release_number_is_one_line_error():
  with pytest.raises(ValueError, match="not a release number"):
    gpu_atomics.release("nightly")


def test_the_option_joins_the_flags_once_and_keeps_every_other_flag():
  assert gpu_atomics.with_option("") == OPTION_FLAG
  deterministic = "--xla_gpu_deterministic_ops=true"
  assert gpu_atomics.with_option(deterministic) == f"{deterministic} {OPTION_FLAG}"
  # XLA keeps the last copy of a flag, so an existing LLVM option list is extended, not repeated.
  joined = gpu_atomics.with_option("--xla_backend_extra_options=-foo,-bar --x=1")
  assert joined == "--xla_backend_extra_options=-foo,-bar,-nvptx-allow-ftz-atomics --x=1"
  assert gpu_atomics.with_option(joined) == joined


def test_flags_are_needed_only_with_an_affected_jaxlib_and_a_cuda_plugin():
  env = {"XLA_FLAGS": "--xla_gpu_deterministic_ops=true"}
  assert gpu_atomics.flags_needed("0.10.2", True, env) == gpu_atomics.with_option(env["XLA_FLAGS"])
  assert gpu_atomics.flags_needed("0.10.2", False, env) is None  # no GPU plugin: CPU only
  assert gpu_atomics.flags_needed("0.11.2", True, env) is None  # fixed release
  assert gpu_atomics.flags_needed("0.10.1", True, env) is None  # never had the loop
  assert gpu_atomics.flags_needed("0.10.2", True, {**env, "NERF_JAX_CAS_ATOMICS": "1"}) is None
  assert gpu_atomics.flags_needed("0.10.2", True, {**env, "NERF_JAX_CAS_ATOMICS": "0"})
  assert gpu_atomics.flags_needed("0.10.2", True, {"XLA_FLAGS": OPTION_FLAG}) is None
  assert gpu_atomics.flags_needed("0.10.2", True, {"XLA_FLAGS": "--xla_gpu_ftz=true"}) is None


def _python(code):
  """Run code in a fresh interpreter with this process's environment; CompletedProcess."""
  return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                        env=os.environ.copy(), timeout=120)


# A scatter-add with every update on one row (the trap's worst case), checked exactly.
SCATTER = ("import jax, jax.numpy as jnp; "
           "x = jax.jit(lambda i: jnp.zeros(3).at[i].add(0.5))(jnp.zeros(64, jnp.int32)); "
           "assert x.tolist() == [32.0, 0.0, 0.0], x; ")


def test_apply_before_jax_starts_sets_flags_this_jaxlib_accepts():
  """With a CUDA plugin (pretended), `apply` adds the option exactly on an affected jaxlib, and
  XLA starts with it and scatters correctly (an option LLVM does not know aborts the process,
  which the second run shows)."""
  result = _python("import os; from nerf_jax.backend import gpu_atomics as g; "
                   "g._cuda_plugin_installed = lambda: True; print(g.apply()); " + SCATTER +
                   "print(os.environ['XLA_FLAGS'])")
  assert result.returncode == 0, result.stderr[-2000:]
  applied, flags = result.stdout.split("\n")[:2]
  jaxlib = importlib.metadata.version("jaxlib")
  assert applied == str(gpu_atomics.affected(jaxlib))
  assert (OPTION_FLAG in flags) is gpu_atomics.affected(jaxlib)
  bogus = _python("import os; os.environ['XLA_FLAGS'] = "
                  "'--xla_backend_extra_options=-nvptx-no-such-option'; " + SCATTER)
  assert bogus.returncode != 0 and "no-such-option" in bogus.stderr


def test_apply_after_jax_started_says_how_in_one_line_and_changes_nothing():
  result = _python("import os; from nerf_jax.backend import gpu_atomics as g; " + SCATTER +
                   "g._cuda_plugin_installed = lambda: True; g._jaxlib_version = lambda: '0.10.2'; "
                   "before = os.environ.get('XLA_FLAGS'); print(g.apply()); "
                   "print(os.environ.get('XLA_FLAGS') == before)")
  assert result.returncode == 0, result.stderr[-2000:]
  assert result.stdout.split() == ["False", "True"]
  said = [line for line in result.stderr.splitlines() if "jax#38806" in line]
  assert len(said) == 1 and OPTION_FLAG in said[0] and "XLA_FLAGS=" in said[0]


def test_describe_names_the_jaxlib_and_its_atomics(monkeypatch):
  monkeypatch.setattr(gpu_atomics, "_jaxlib_version", lambda: "0.11.2")
  assert gpu_atomics.describe() == "jaxlib 0.11.2: native float atomics"
  monkeypatch.setattr(gpu_atomics, "_jaxlib_version", lambda: "0.10.2")
  monkeypatch.setenv("XLA_FLAGS", "")
  assert "CAS-loop" in gpu_atomics.describe()
  monkeypatch.setenv("XLA_FLAGS", OPTION_FLAG)
  assert gpu_atomics.describe().endswith("through -nvptx-allow-ftz-atomics")
