"""The benchmark's index (the docstring of nerf_jax/bench/__init__.py) names every module of
nerf_jax/bench once, with what it is for, and no module that is not there."""

import pathlib
import re

from nerf_jax import bench


def test_the_index_names_every_bench_module_once():
  modules = sorted(p.name for p in pathlib.Path(bench.__file__).parent.glob("*.py")
                   if p.name != "__init__.py")
  listed = re.findall(r"^(\w+\.py) +\S", bench.__doc__, flags=re.MULTILINE)
  assert len(modules) > 20
  assert sorted(listed) == modules
