"""Scores and images: test-view evaluation, PSNR/SSIM, LPIPS, image conversion."""
