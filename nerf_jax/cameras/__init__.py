"""Cameras and rays: get_rays and the Rays pytree, NDC, video paths, pose refinement."""
