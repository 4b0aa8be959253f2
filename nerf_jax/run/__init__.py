"""The entry layer: training (train_lib.py) and its wiring: configs by name, the experiment built
from a config and its data, each layer's settings and components, what a checkpoint records,
auto, what render.py writes."""
