"""nerf_jax: a pure-JAX, functional NeRF."""

import importlib.util as _util
import pathlib as _pathlib
import sys as _sys


def _use_this_checkouts_configs():
  """In a checkout (configs/ beside this package, not inside it), `nerf_jax.configs` is that
  checkout's configs/ folder, whichever checkout an editable install points at: a second clone
  or worktree on PYTHONPATH otherwise loads the installed one's default.py. An installed wheel
  holds configs/ inside the package, where the normal import finds it."""
  here = _pathlib.Path(__file__).resolve().parent
  folder = here.parent / "configs"
  if (here / "configs").is_dir() or not (folder / "__init__.py").is_file():
    return
  spec = _util.spec_from_file_location("nerf_jax.configs", folder / "__init__.py",
                                       submodule_search_locations=[str(folder)])
  module = _util.module_from_spec(spec)
  _sys.modules["nerf_jax.configs"] = module
  spec.loader.exec_module(module)
  globals()["configs"] = module  # as an import of the subpackage sets it


_use_this_checkouts_configs()

# Before jax reads XLA_FLAGS: native float atomics on the jaxlibs that lost them.
from nerf_jax.backend import gpu_atomics as _gpu_atomics  # noqa: E402

_gpu_atomics.apply()

# NERF_JAX_EMULATE takes effect here, before anything is compiled (backend/precision.py).
from nerf_jax.backend import precision as _precision  # noqa: E402,F401

__version__ = "0.1.0"
