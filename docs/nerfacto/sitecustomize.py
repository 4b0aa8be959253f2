# nerfacto builds torchmetrics' LPIPS at start, which downloads weights; this machine has no
# network, so LPIPS is replaced by a stub (we score PSNR/SSIM/LPIPS ourselves from the renders).
import torch
import torchmetrics.image.lpip as _lpip


class _NoLPIPS(torch.nn.Module):
  def __init__(self, *args, **kwargs):
    super().__init__()

  def forward(self, a, b):
    return torch.zeros(())


_lpip.LearnedPerceptualImagePatchSimilarity = _NoLPIPS
