"""Training, config-free: the loop and its hooks, the jitted step, the optimiser, the state,
batches, regularisers, the time budget, devices, checkpoints, progress and summaries."""
