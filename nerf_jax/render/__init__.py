"""From samples to pixels: alpha compositing, backgrounds, the ray renderer, images in chunks,
empty-space skipping, surface export."""
