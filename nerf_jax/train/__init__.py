"""Training: the loop, the jitted step, batches, regularisers, the time budget, devices,
checkpoints, progress and summaries."""
