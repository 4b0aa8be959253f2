"""The entry layer's wiring: configs by name, the experiment built from a config and its data, auto,
what render.py writes."""
