"""The numerics the models share: in-place buffers, integrators, Levenberg-Marquardt, smooth steps, and the
statistics of correlated residuals."""
