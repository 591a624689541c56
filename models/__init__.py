"""Analytic layered BSDF models, their integration onto slices and their errors."""
