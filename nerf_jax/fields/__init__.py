"""The radiance field: the Field (field.py), its position and direction encodings (encodings/: one
module per encoding, its math and settings), the networks that read them (networks/: the only
Flax modules), the parts' calling conventions (protocol.py), the registries that find both by
name (registry.py), density activations, scene contraction and the proposal density fields."""
