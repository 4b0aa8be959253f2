"""Render chosen test views of a nerfstudio run to an .npz (predictions, ground truths), to be
scored by score_views.py with nerf_jax's own metrics. Runs in nerfstudio's environment, with
this folder on PYTHONPATH (sitecustomize.py stubs nerfstudio's LPIPS):

  PYTHONPATH=docs/nerfacto python docs/nerfacto/render_views.py CONFIG_YML OUT_NPZ VIEW [VIEW ...]
"""
import sys
from pathlib import Path

import numpy as np
import torch
from nerfstudio.utils.eval_utils import eval_setup

# nerfstudio 1.1.5 loads its own checkpoints with torch.load's old default (torch >= 2.6 made
# weights_only=True the default, which refuses them); these are checkpoints we just wrote.
_load = torch.load
torch.load = lambda *a, **k: _load(*a, **{**k, "weights_only": False})


def main():
  config_path, out, views = Path(sys.argv[1]), sys.argv[2], [int(v) for v in sys.argv[3:]]
  _, pipeline, ckpt, step = eval_setup(config_path, eval_num_rays_per_chunk=4096, test_mode="test")
  dataset = pipeline.datamanager.eval_dataset
  preds, refs = [], []
  for i in views:
    camera = dataset.cameras[i:i + 1].to(pipeline.device)
    with torch.no_grad():
      rgb = pipeline.model.get_outputs_for_camera(camera)["rgb"]
    preds.append(rgb.clamp(0, 1).cpu().numpy())
    refs.append(dataset[i]["image"][..., :3].cpu().numpy())
    print(f"view {i}: {dataset.image_filenames[i].name}", flush=True)
  np.savez(out, preds=np.stack(preds), refs=np.stack(refs), views=np.array(views), step=step)
  print(f"checkpoint step {step}: {out}")


if __name__ == "__main__":  # the data manager spawns processes that import this file
  main()
