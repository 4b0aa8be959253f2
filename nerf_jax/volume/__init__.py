"""The volume rendering quadrature (optical depth, alpha, transmittance, weights): below the
samplers and the renderers, which both use it."""
