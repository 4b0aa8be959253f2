"""Where along each ray the field is queried: stratified and inverse-CDF sampling, the Sampler, the
occupancy grid and the visual hull that seeds it."""
