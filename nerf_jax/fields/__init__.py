"""The radiance field family: the Field, its networks (the only Flax modules), density activations,
scene contraction, and the encodings in encodings/."""
