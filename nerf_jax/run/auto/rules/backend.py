"""The backend: the representation the rules chose (Rule.representation), as measured on a CPU,
or its configs/gpu/ counterpart on a GPU; its lines name both."""

from nerf_jax.run.auto.rule import Rule

# On a GPU backend, the config that takes each CPU choice's place: the configs/gpu/ one where it
# won on an H200 (docs/gpu.md, 2026-11-28: gpu/lego 32.63 dB on lego in 60 s against detail.py's
# 30.45 in 120 s; gpu/llff 23.85 on fern against llff.py's 23.34), the CPU's own where it lost
# (gpu/capture 19.57 dB on fox in 60 s against capture.py's 27.36).
GPU_CONFIGS = {"fast": "gpu/lego", "detail": "gpu/lego", "llff": "gpu/llff",
               "capture": "capture"}


def for_backend(chosen, backend):
  """(config name, one line saying why) of the CPU choice `chosen` ('fast', 'detail', 'llff',
  'capture') on `backend` (jax.default_backend(): 'cpu', 'gpu', ...): a GPU's config of
  GPU_CONFIGS on 'gpu', else `chosen` itself, as measured on a CPU."""
  if backend != "gpu":
    return chosen, (f"backend {backend}: configs/{chosen}.py, the configs measured on a CPU "
                    "(a GPU backend takes configs/gpu/)")
  gpu = GPU_CONFIGS[chosen]
  if gpu == chosen:
    return gpu, (f"backend gpu: configs/{gpu}.py, as on a CPU: it beat configs/gpu/'s "
                 "config of its kind on an H200 (docs/gpu.md)")
  return gpu, (f"backend gpu: configs/{gpu}.py, sized for a GPU (measured on an H200: "
               f"docs/gpu.md), in place of the CPU's configs/{chosen}.py")


def decide(context):
  """({}, [the backend's line, the representation's])."""
  return {}, [context.backend_line, f"representation: configs/{context.chosen}.py"]


RULE = Rule("backend", decide, row="backend")
