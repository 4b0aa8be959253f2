"""Native float atomics for GPU scatter-adds on the jaxlib releases that lost them.

jaxlib 0.10.2 to 0.11.0 bundle an LLVM whose NVPTX backend lowers a float32 `atomicrmw fadd`
to a compare-and-swap retry loop unless the kernel flushes denormals (the native
`atom.add.f32` on global memory flushes them; LLVM commit 8ae895af32cc). XLA compiles every
scatter-add that way, and a CAS loop collapses when many updates hit one row: 450-2000 times
slower (jax#38806, openxla/xla#46225). The grid and hash tables' gradients are such
scatter-adds: each sample adds its 8 corners at every level, and a coarse level has few rows.
jaxlib 0.11.1 has the LLVM fix (kUPS#248 reports it fixed there; the GPU script's scatter check,
bench/scatter_add.py, measures it); 0.10.1 and older never lost the native atomic.

The fix for the affected releases is LLVM's own option `-nvptx-allow-ftz-atomics`, passed
through XLA_FLAGS before jax starts its backends. Its price: a partial sum below float32's
smallest normal (1.2e-38) is flushed to zero inside the atomic, as it was before 0.10.2. Adam
cannot use such a gradient g anyway: g^2 underflows, so the update is lr·(1 - b1)·g / eps <=
1e-2 · 0.1 · 1.2e-38 / 1e-15 ~ 1e-26, below an ulp of any table entry it could change.

`apply()` runs when nerf_jax is imported. It changes nothing unless the jaxlib is affected and
a CUDA plugin is installed. `NERF_JAX_CAS_ATOMICS=1` in the environment keeps jaxlib's loop.
"""

import importlib.metadata
import importlib.util
import os
import re
import sys

OPTION = "-nvptx-allow-ftz-atomics"
EXTRA_OPTIONS = "--xla_backend_extra_options="  # XLA's flag that hands options to LLVM
AFFECTED = ((0, 10, 2), (0, 11, 0))  # jaxlib releases with the CAS loop, both included
OPT_OUT = "NERF_JAX_CAS_ATOMICS"
CUDA_PLUGINS = ("jax_cuda12_plugin", "jax_cuda13_plugin")


def release(version):
  """(major, minor, patch) ints of a version string such as '0.10.2' or '0.11.0.dev2026'."""
  match = re.match(r"(\d+)\.(\d+)\.(\d+)", version)
  if match is None:
    raise ValueError(f"not a release number: {version!r}")
  return tuple(int(part) for part in match.groups())


def affected(jaxlib_version):
  """Whether this jaxlib's GPU scatter-add is a CAS loop (jax#38806)."""
  return AFFECTED[0] <= release(jaxlib_version) <= AFFECTED[1]


def with_option(xla_flags, option=OPTION):
  """XLA_FLAGS with `option` added to its LLVM options (one XLA flag holds them, comma-separated;
  a second copy of the flag would replace the first)."""
  tokens = xla_flags.split()
  for i, token in enumerate(tokens):
    if token.startswith(EXTRA_OPTIONS):
      options = [o for o in token[len(EXTRA_OPTIONS):].split(",") if o]
      if option not in options:
        tokens[i] = EXTRA_OPTIONS + ",".join(options + [option])
      return " ".join(tokens)
  return " ".join(tokens + [EXTRA_OPTIONS + option])


def has_option(xla_flags):
  """Whether XLA_FLAGS already makes scatter-adds use the native atomic (the option, or XLA's
  flush-to-zero for whole kernels)."""
  return OPTION in xla_flags or "--xla_gpu_ftz=true" in xla_flags.lower()


def flags_needed(jaxlib_version, cuda_plugin, environ):
  """The XLA_FLAGS this process needs, or None when it needs no change.

  jaxlib_version: str; cuda_plugin: bool, a jax CUDA plugin is installed; environ: a mapping
  like os.environ (XLA_FLAGS and the opt-out are read from it).
  """
  flags = environ.get("XLA_FLAGS", "")
  if (environ.get(OPT_OUT, "") not in ("", "0") or not cuda_plugin
      or not affected(jaxlib_version) or has_option(flags)):
    return None
  return with_option(flags)


def _jaxlib_version():
  try:
    return importlib.metadata.version("jaxlib")
  except importlib.metadata.PackageNotFoundError:
    return "0.0.0"


def _cuda_plugin_installed():
  return any(importlib.util.find_spec(name) is not None for name in CUDA_PLUGINS)


def _backends_started():
  """Whether jax has read XLA_FLAGS already (it does so once, when it starts its backends)."""
  if "jax" not in sys.modules:
    return False
  from jax._src import xla_bridge  # pylint: disable=import-outside-toplevel
  return xla_bridge.backends_are_initialized()


def apply():
  """Add OPTION to XLA_FLAGS when this process needs it (see the module). Returns whether it
  did. When jax's backends have already started, it is too late: one line on stderr says how
  to set it, and the run goes on with the slow loop."""
  flags = flags_needed(_jaxlib_version(), _cuda_plugin_installed(), os.environ)
  if flags is None:
    return False
  if _backends_started():
    print(f"nerf_jax: jaxlib {_jaxlib_version()}'s GPU scatter-add is a CAS loop, up to 2000x "
          f"slower on the tables' gradients (jax#38806); start Python with "
          f"XLA_FLAGS='{flags}' or import nerf_jax before running jax", file=sys.stderr)
    return False
  os.environ["XLA_FLAGS"] = flags
  return True


def describe():
  """One phrase for reports: this jaxlib and whether its scatter-adds use the native atomic."""
  version = _jaxlib_version()
  if not affected(version):
    return f"jaxlib {version}: native float atomics"
  if has_option(os.environ.get("XLA_FLAGS", "")):
    return f"jaxlib {version}: native float atomics through {OPTION}"
  return f"jaxlib {version}: CAS-loop atomics on a GPU (jax#38806)"
