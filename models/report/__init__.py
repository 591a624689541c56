"""Reports over a results directory of ``gonio database simulate``: error tables, figure-4-style
plots, per-material figures, the reproduction checks of Bati et al. 2019 (section 4.2) and a static
HTML browser; ``plot_file`` draws the per-material figures of one simulated file (``gonio plot``),
``plot_furnace`` the directional-albedo figure of ``gonio furnace --plot`` (``docs/furnace.md``).
The report directory, its files and the caching rules: ``docs/report.md``."""

from models.report.build import Progress, ReportSummary, build_report
from models.report.figures import model_style, plot_file
from models.report.furnace import furnace_figure, plot_furnace
from models.report.results import MaterialResult, ReportError, ReportMaterial, open_results

__all__ = ["build_report", "ReportSummary", "Progress", "plot_file", "model_style", "open_results",
           "ReportMaterial", "MaterialResult", "ReportError", "furnace_figure", "plot_furnace"]
