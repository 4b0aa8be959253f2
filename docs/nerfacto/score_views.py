"""Score render_views.py's .npz with nerf_jax's own metrics (the PSNR, SSIM and LPIPS of
train.py's metrics.json). Runs in nerf_jax's environment:

  python docs/nerfacto/score_views.py OUT_NPZ
"""
import sys
import numpy as np
from nerf_jax.evaluate import lpips, metrics
d = np.load(sys.argv[1])
rows = []
for v, p, r in zip(d["views"], d["preds"], d["refs"]):
  row = (float(metrics.psnr(p, r)), float(metrics.ssim(p, r)), float(lpips.lpips(p, r)))
  rows.append(row)
  print(f"view {v}: PSNR {row[0]:.2f} SSIM {row[1]:.4f} LPIPS {row[2]:.4f}")
m = np.mean(rows, axis=0)
print(f"mean PSNR {m[0]:.2f} SSIM {m[1]:.4f} LPIPS {m[2]:.4f} (checkpoint step {int(d['step'])})")
