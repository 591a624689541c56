"""The figure of ``gonio furnace --plot``: directional albedo against the incident angle, the
simulation with its error bars and one line per model (``docs/furnace.md``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from models.furnace import FurnaceResult
from models.report.panels import save_figure

#: channel names and colours of the three panels
CHANNELS = (("R", "tab:red"), ("G", "tab:green"), ("B", "tab:blue"))
#: error bars of the simulation: this many standard errors
SIGMAS = 2.0


def furnace_figure(result: FurnaceResult):
    """A matplotlib figure: one panel per RGB channel (a spectral run: per linear sRGB channel of
    its bins, ``docs/spectral.md`` section 4), E(theta_l) of the simulation (+- 2 standard errors)
    and of every evaluated model, with the white-furnace level 1 dashed."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from models.report.figures import model_style

    fig, axes = plt.subplots(1, 3, figsize=(17, 4.8), sharey=True, layout="constrained")
    t = np.asarray(result.incident_deg)
    styles = model_style(result.models.albedo)
    for c, (ax, (label, colour)) in enumerate(zip(axes, CHANNELS)):
        ax.axhline(1.0, color="0.6", lw=1.0, ls="--", label="white furnace (E = 1)")
        ax.errorbar(t, result.albedo[:, c], yerr=SIGMAS * result.stderr[:, c], fmt="o", ms=4, color="black",
                    capsize=3, label=f"simulation (+- {SIGMAS:g} s.e.)", zorder=5)
        for name, a in result.models.albedo.items():
            st = styles[name]
            ax.plot(t, a[:, c], lw=1.5, ms=4, color=st["colour"], marker=st["marker"], label=name)
        ax.set_title(f"channel {label}" if result.spectral is None else f"linear sRGB {label} of "
                     f"{result.spectral.bins} wavelength bins", color=colour)
        ax.set_xlabel("incident angle theta_l (degrees)")
        ax.set_xlim(0.0, 90.0)
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("directional albedo E (fraction of incident flux)")
    handles, labels = axes[-1].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=8)   # beside the panels: hides no curve
    per = "angle" if result.spectral is None else "angle and wavelength bin"
    fig.suptitle(f"{result.material}: directional albedo (reflected + transmitted), {result.rays:,} rays per {per}")
    return fig


def plot_furnace(result: FurnaceResult, path: str | Path) -> Path:
    """Draw :func:`furnace_figure` into the PNG ``path`` (atomically); returns the path."""
    import matplotlib.pyplot as plt
    fig = furnace_figure(result)
    try:
        save_figure(fig, Path(path))
    finally:
        plt.close(fig)
    return Path(path)
