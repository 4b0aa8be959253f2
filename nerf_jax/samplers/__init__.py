"""Where along each ray the field is queried: the built-in Sampler (placement.py), the stratified
and inverse-CDF spacing of distances (spacing.py), the occupancy grid and the visual hull that
seeds it, the proposal sampler; samplers by name (registry.py)."""
