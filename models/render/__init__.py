"""Lit-sphere renderings of a simulated material and the analytic models (``gonio render``, the
report's spheres): a pure-numpy orthographic view of a unit sphere under one directional light,
the reference interpolated from a simulated file, one exposure for all panels. Conventions,
interpolation, exposure and colour space: ``docs/render.md``; a polarized file's degree and angle
of linear polarization on the sphere: :mod:`models.render.stokes`."""

from models.render.compare import (REFERENCE, SphereSet, comparison_figure, model_names, render_file,
                                   render_spheres, render_views, view_text)
from models.render.figure import write_png
from models.render.modelbsdf import THETA_STEP_DEG, ModelBSDF, node_step_deg
from models.render.reference import Reference, SlicesBSDF, open_reference, slices_reference
from models.render.sphere import BRDF, BTDF, IRRADIANCE, RenderError, SphereView, shade_views
from models.render.stokes import NotPolarized, StokesSphere, render_stokes, render_stokes_file
from models.render.tonemap import EXPOSURE_PERCENTILE, EXPOSURE_RULE, EXPOSURE_WHITE, exposure, srgb_oetf

__all__ = ["SphereView", "shade_views", "RenderError", "BRDF", "BTDF", "IRRADIANCE", "Reference", "SlicesBSDF", "open_reference",
           "slices_reference", "ModelBSDF", "THETA_STEP_DEG", "node_step_deg", "SphereSet", "render_spheres", "render_views", "render_file",
           "comparison_figure", "model_names", "view_text", "REFERENCE", "write_png", "exposure", "srgb_oetf",
           "EXPOSURE_PERCENTILE", "EXPOSURE_WHITE", "EXPOSURE_RULE", "NotPolarized", "StokesSphere", "render_stokes",
           "render_stokes_file"]
