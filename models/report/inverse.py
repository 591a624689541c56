"""Reports and figures of the inverse method (Bati 2021; the application floor).

The validation report of :func:`models.inverse.run_validation` (:func:`write_report`:
``report.md``, ``index.html``, ``validation.json``, the figure-25-style scatter plots and one
ring-profile figure per simulated case), :func:`classes_figure` (the equivalence classes of an
:class:`~models.inverse.Inversion`, ``gonio invert --classes``) and :func:`material_text` (the
material file of ``gonio invert --out``, ``docs/material-format.md``, with the request as
comments). Every file is written atomically (:func:`goniometer.atomic.write_bytes`). The method
and the validation: ``docs/inverse.md``.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from goniometer import atomic
from models import belcour
from models.belcour import variance_to_roughness
from models.inverse import (FORWARD_RTOL, SIGMA_RES, CaseResult, Inversion, LobeCheck, OneLayerDielectricClass,
                            TwoLayerClass, conductor_point, fgd_for, jsonable, lobe_albedo, lobe_ring_fractions,
                            validation_json)
from models.report import files
from models.report.numbers import number
from models.report.panels import save_figure


# ============================================================================ material file (gonio invert --out)

def material_text(inv, stack, checks) -> str:
    """The TOML material (docs/material-format.md) with the request as comments."""
    head = ["# written by `gonio invert` (Bati 2021 inverse method, models.inverse)",
            f"# base: {inv.base}; eta_max = {inv.options.eta_max:g}; lobes (top first), requested -> forward model:"]
    for k, (lobe, c) in enumerate(zip(inv.lobes, checks)):
        sol = inv.solutions[k]
        head.append(f"#   lobe {k + 1}: {lobe.describe()} -> R={rgb_text(c.R_forward)} "
                    f"sigma={rgb_text(c.sigma_forward)}")
        head.append("#     choices: " + ", ".join(f"{key}={value_text(v)}" for key, v in sol.choices.items()))
    if inv.searched:
        head.append("#   (some default choices were moved by the search so that every lobe is achievable)")
    return "\n".join(head) + "\n" + stack.to_toml()


def rgb_text(a: Any) -> str:
    """An RGB value for tables and comments: one number if the channels are equal, else ``[r, g, b]`` (5 digits)."""
    a = np.atleast_1d(np.asarray(a, dtype=float))
    if a.size == 1 or (a.size == 3 and np.ptp(a) == 0):
        return f"{a[0]:.5g}"
    return "[" + ", ".join(f"{x:.5g}" for x in a) + "]"


def value_text(v: Any) -> str:
    """A choice's value for tables and comments: strings as they are, numbers and RGB as :func:`rgb_text`."""
    if isinstance(v, str):
        return v
    a = np.atleast_1d(np.asarray(v, dtype=float))
    return rgb_text(a) if a.size in (1, 3) else str(v)


# ============================================================================ validation report

def write_json(path: str | os.PathLike, obj: Any) -> None:
    """``obj`` made of JSON values (:func:`models.inverse.jsonable`) written by the report's JSON
    writer (:func:`models.report.files.write_json`, indent 2), atomically."""
    files.write_json(Path(path), jsonable(obj), indent=2)


def _save_figure(fig, path: Path) -> None:
    """The pyplot figure ``fig`` as a PNG (:func:`models.report.panels.save_figure`), then closed."""
    import matplotlib.pyplot as plt
    try:
        save_figure(fig, path, tight=True)
    finally:
        plt.close(fig)


def _f(x: Any, fmt: str = ".4g") -> str:
    return number(x, fmt, missing="-")


def _pct(x: Any) -> str:
    a = np.atleast_1d(np.asarray(x, dtype=float))
    return " ".join(f"{100 * v:+.2f}%" for v in a)


_SPREAD_NOTE = ("forward variances differ between channels: a coloured lobe below an interface has a "
                "channel-dependent inter-reflection factor m (eq. 19) but one achromatic roughness; the minimax "
                "choice halves the spread")


def _why(case: CaseResult, k: int, c: LobeCheck) -> str:
    """A short explanation of a lobe's remaining differences."""
    notes = []
    if c.sigma_requested > 0 and np.max(np.abs(c.sigma_rel_error)) > 1e-4 and np.ptp(c.sigma_forward) > 0:
        notes.append(_SPREAD_NOTE)
    if np.max(np.abs(c.R_rel_error)) > 1e-6:
        notes.append("FGD split slice of the forward model (relative index < 1) differs slightly from the "
                     "inverse's unsplit quadrature")
    if c.R_simulated is not None:
        z = np.abs(c.R_simulated - c.R_forward) / np.maximum(c.R_simulated_err, 1e-12)
        if np.any(z > 5):
            notes.append("simulated energy differs from Belcour's forward model beyond noise "
                         "(the forward model is approximate for internal lobes)")
    if c.sigma_simulated is not None and c.sigma_requested >= SIGMA_RES:
        z = np.abs(c.sigma_simulated - c.sigma_forward) / np.maximum(c.sigma_simulated_err, 1e-12)
        if np.any(z > 5):
            notes.append("simulated variance differs from the forward model beyond noise (Belcour's variance "
                         "adding through rough interfaces and its Jacobians are approximate; the simulated lobe is "
                         "not exactly GGX)")
    if c.group:
        notes.append(f"variance too close to lobe(s) {c.group} to separate at normal incidence")
    if c.sigma_requested < SIGMA_RES and c.sigma_simulated is not None:
        notes.append("smooth lobe: the fitted variance is only an upper bound (first ring)")
    return "; ".join(notes)


def report_markdown(results: Sequence[CaseResult], simulate: bool, figures: dict[str, str]) -> str:
    lines = ["# Inverse method validation (Bati 2021)", ""]
    doc = validation_json(results, simulate)["summary"]
    lines += [f"{doc['cases']} cases, {doc['achievable']} achievable; largest forward-model error over all lobes "
              f"and channels: R {100 * (doc['max_R_forward_rel_error'] or 0):.3f}%, sigma "
              f"{100 * (doc['max_sigma_forward_error'] or 0):.3f}% (figure 25; tolerance {100 * FORWARD_RTOL:g}%).", ""]
    if doc["unexpected"]:
        lines += [f"**Unexpected achievability:** {', '.join(doc['unexpected'])}", ""]
    if "scatter" in figures:
        lines += [f"![requested vs obtained]({figures['scatter']})", ""]
    lines += ["Columns: requested, Belcour forward model of the retrieved stack (error), "
              + ("goniometer simulation at normal incidence (fit of GGX lobes, +- 1 standard error). " if simulate else "")
              + "Sigma errors are relative, absolute for smooth lobes.", ""]
    for r in results:
        lines.append(f"## {r.case.name}")
        lines.append("")
        if r.case.note:
            lines += [r.case.note, ""]
        lines.append(f"base: {r.case.base}; lobes: " + "; ".join(lb.describe() for lb in r.case.lobes)
                     + (f"; picks: `{r.case.pick}`" if r.case.pick else ""))
        lines.append("")
        if not r.achievable:
            exp = "" if r.case.expect_achievable else " (expected)"
            lines += [f"**Not physically achievable{exp}:** {r.inversion.reason}", ""]
            continue
        if not r.case.expect_achievable:
            lines += ["**Achievable although the case expected otherwise.**", ""]
        lines.append("Retrieved stack (top first): " + _stack_text(r.stack_json)
                     + (" -- default picks moved by the search (choice 6)" if r.inversion.searched else ""))
        lines.append("")
        hdr = "| lobe | R requested | R forward | error | sigma req. | sigma forward | error |"
        sep = "|---|---|---|---|---|---|---|"
        if simulate:
            hdr += " R simulated | sigma simulated | notes |"
            sep += "---|---|---|"
        else:
            hdr += " notes |"
            sep += "---|"
        lines += [hdr, sep]
        for k, c in enumerate(r.checks):
            row = (f"| {k + 1} ({r.case.lobes[k].layers}L) | {_f(c.R_requested)} | {_f(c.R_forward)} | "
                   f"{_pct(c.R_rel_error)} | {c.sigma_requested:.4g} | {_f(c.sigma_forward)} | "
                   + (_pct(c.sigma_rel_error) if c.sigma_requested > 0 else _f(c.sigma_rel_error, '.2e')) + " |")
            if simulate:
                if c.R_simulated is not None:
                    row += (f" {_f(c.R_simulated)} +- {_f(c.R_simulated_err, '.1g')} | {_f(c.sigma_simulated)} +- "
                            f"{_f(c.sigma_simulated_err, '.1g')} |")
                else:
                    row += f" (group {c.group}) | (group) |"
            row += f" {_why(r, k, c)} |"
            lines.append(row)
        lines.append("")
        if simulate and r.simulated is not None:
            for g in r.simulated["groups"][1:]:
                if len(g["lobes"]) > 1:
                    req = np.sum([r.case.lobes[k - 1].rgb for k in g["lobes"]], axis=0)
                    lines.append(f"- lobes {g['lobes']} fitted together: R {_f(g['R'])} (requested sum {_f(req)}), "
                                 f"sigma {_f(g['sigma'])}")
            if r.top_order1 is not None:
                t = r.top_order1
                lines.append(f"- top interface (bounce order 1): simulated {_f(t['simulated'])} +- {_f(t['stderr'], '.1g')}"
                             f", forward FGD {_f(t['fgd'])}")
            chi = [x for x in list(r.simulated["chi2_dof_top"]) + list(r.simulated["chi2_dof"]) if np.isfinite(x)]
            lines.append(f"- fit chi2/dof per channel: order 1 {_f(r.simulated['chi2_dof_top'], '.3g')}; internal "
                         f"{_f(r.simulated['chi2_dof'], '.3g') if r.simulated['chi2_dof'] else '-'}"
                         + (" (well above 1: the simulated lobes are not exactly GGX; standard errors are scaled up "
                            "accordingly)" if chi and max(chi) > 3 else ""))
            if r.case.name in figures:
                lines.append(f"\n![profile]({figures[r.case.name]})")
            lines.append("")
    return "\n".join(lines) + "\n"


def _stack_text(sj: dict | None) -> str:
    if not sj:
        return "-"
    parts = []
    for layer in sj["layers"]:
        if layer["type"] == "interface":
            ior = layer["ior"]
            ext = layer.get("extinction")
            ior_t = _f(ior, ".4g") if isinstance(ior, list) else f"{ior:.4g}"
            parts.append(f"interface(alpha={layer['roughness']:.4g}, eta={ior_t}"
                         + (f", kappa={_f(ext, '.4g')}" if ext else "") + ")")
        elif layer["type"] == "medium":
            parts.append(f"medium(tau={_f(layer['optical_depth'], '.3g')})")
    return " / ".join(parts)


def scatter_figure(results: Sequence[CaseResult], simulate: bool):
    """Figure-25-style plots: obtained vs requested energy and variance, per channel."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(10, 4.6))
    colours = ("tab:red", "tab:green", "tab:blue")
    for ax, what in zip(axes, ("R", "sigma")):
        lim = 0.0
        for r in results:
            for c in r.checks:
                req = c.R_requested if what == "R" else np.full(3, c.sigma_requested)
                fw = c.R_forward if what == "R" else c.sigma_forward
                sim = c.R_simulated if what == "R" else c.sigma_simulated
                for ch in range(3):
                    ax.plot(req[ch], fw[ch], "o", ms=5, mfc="none", color=colours[ch])
                    if simulate and sim is not None:
                        ax.plot(req[ch], sim[ch], "x", ms=5, color=colours[ch])
                lim = max(lim, float(np.max(req)), float(np.max(fw)))
        lim = lim * 1.08 if lim > 0 else 1.0
        ax.plot([0, lim], [0, lim], "k:", lw=1)
        ax.set_xlim(0, lim)
        ax.set_ylim(0, lim)
        ax.set_xlabel(f"requested {what}")
        ax.set_ylabel(f"obtained {what}")
        ax.set_title(("energy" if what == "R" else "variance") + " (o forward model" + (", x simulation)" if simulate else ")"))
    fig.tight_layout()
    return fig


def profile_figure(r: CaseResult):
    """Ring energies per unit theta_v (log scale) of the simulated slice with the fitted lobes and
    Belcour's forward prediction, per channel."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    rings = r.rings
    assert rings is not None and r.simulated is not None
    edges = rings.theta_h_edges
    tv = np.degrees(2.0 * edges)
    width = np.diff(tv)
    centre = 0.5 * (tv[:-1] + tv[1:])
    fs = belcour.stack_statistics(r.inversion.stack(), 1.0)
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8), sharey=True)
    for ch, ax in enumerate(axes):
        d = rings.energy[ch] / width
        ax.errorbar(centre, d, yerr=rings.stderr[ch] / width, fmt=".", ms=3, color="k", lw=0.6, label="simulation")
        ax.plot(centre, rings.order1[ch] / width, ".", ms=2, color="0.6", label="simulation, order 1")
        total = np.zeros_like(d)
        for g in r.simulated["groups"]:
            a = g["alpha"][ch]
            if not np.isfinite(a):
                continue
            m = g["R"][ch] * lobe_ring_fractions(edges, a) / width
            total += m
            ax.plot(centre, m, "--", lw=1, label=f"fit {g['part']}: lobe(s) {g['lobes']}")
        ax.plot(centre, total, "-", color="tab:orange", lw=1.2, label="fit total")
        fw = np.zeros_like(d)
        for lobe in fs.lobes:
            a = variance_to_roughness(lobe.variance[ch])
            if lobe.energy[ch] > 0:
                fw += lobe.energy[ch] * lobe_albedo(a) * lobe_ring_fractions(edges, a) / width
        ax.plot(centre, fw, ":", color="tab:purple", lw=1.4, label="Belcour forward")
        ax.set_yscale("log")
        ax.set_xscale("log")
        ax.set_xlim(centre[0] / 1.5, 95.0)
        ax.set_xlabel("theta_v (deg)")
        ax.set_title("RGB"[ch])
        pos = d[d > 0]
        if pos.size:
            ax.set_ylim(max(pos.min() * 0.3, pos.max() * 1e-6), pos.max() * 3)
    axes[0].set_ylabel("ring energy / dtheta_v (1/deg)")
    axes[0].legend(fontsize=7)
    fig.suptitle(r.case.name)
    fig.tight_layout()
    return fig


def _html(markdown_text: str) -> str:
    """A minimal HTML rendering of the markdown report (headings, tables, images, paragraphs)."""
    import html as H
    out = ["<!doctype html><meta charset='utf-8'><title>Inverse validation</title>",
           "<style>body{font-family:sans-serif;max-width:1200px;margin:auto}table{border-collapse:collapse;"
           "font-size:13px}td,th{border:1px solid #ccc;padding:2px 6px}img{max-width:100%}</style>"]
    in_table = False
    for line in markdown_text.splitlines():
        if line.startswith("|"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            if set("".join(cells)) <= set("-"):
                continue
            if not in_table:
                out.append("<table>")
                in_table = True
                out.append("<tr>" + "".join(f"<th>{H.escape(c)}</th>" for c in cells) + "</tr>")
            else:
                out.append("<tr>" + "".join(f"<td>{H.escape(c)}</td>" for c in cells) + "</tr>")
            continue
        if in_table:
            out.append("</table>")
            in_table = False
        if line.startswith("# "):
            out.append(f"<h1>{H.escape(line[2:])}</h1>")
        elif line.startswith("## "):
            out.append(f"<h2>{H.escape(line[3:])}</h2>")
        elif line.strip().startswith("![") and "](" in line:
            src = line.split("](", 1)[1].rstrip(")").strip()
            out.append(f"<p><img src='{H.escape(src)}'></p>")
        elif line.strip():
            out.append(f"<p>{H.escape(line)}</p>")
    if in_table:
        out.append("</table>")
    return "\n".join(out) + "\n"


def write_report(results: Sequence[CaseResult], out_dir: str | os.PathLike, simulate: bool) -> dict[str, Path]:
    """Write ``report.md``, ``index.html``, ``validation.json`` and the figures into ``out_dir``."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    figures: dict[str, str] = {}
    achieved = [r for r in results if r.achievable]
    if achieved:
        _save_figure(scatter_figure(achieved, simulate), out / "figure25.png")
        figures["scatter"] = "figure25.png"
    for i, r in enumerate(achieved):
        if r.rings is not None and r.simulated is not None:
            name = f"profile-{i:02d}.png"
            _save_figure(profile_figure(r), out / name)
            figures[r.case.name] = name
    md = report_markdown(results, simulate, figures)
    atomic.write_bytes(out / "report.md", md.encode())
    atomic.write_bytes(out / "index.html", _html(md).encode())
    write_json(out / "validation.json", validation_json(results, simulate))
    return {"markdown": out / "report.md", "html": out / "index.html", "json": out / "validation.json"}


# ============================================================================ equivalence-class figures

_CH = ("tab:red", "tab:green", "tab:blue")


def save_png(fig, path: str | os.PathLike) -> None:
    """Save a matplotlib figure as PNG atomically."""
    _save_figure(fig, Path(path))


def _panel_empty(ax, title: str, reason: str | None) -> None:
    import textwrap
    ax.set_title(title, fontsize=9)
    ax.text(0.5, 0.5, "not physically achievable:\n" + textwrap.fill(reason or "", 50), ha="center", va="center",
            fontsize=7, transform=ax.transAxes, color="firebrick")
    ax.set_xticks([])
    ax.set_yticks([])


def _panel_dielectric1(ax, cls: OneLayerDielectricClass, sol) -> None:
    """Figure 4a / 6 style: R_{n,n+1} = FGD(alpha~, eta1 / eta_n) against eta1 with the targets R'."""
    o = cls.context.options
    etas = np.linspace(1.0, o.eta_max, 300)
    for c in range(3):
        r = [fgd_for(o, cls.alpha_lookup[c], e / cls.context.eta) for e in etas]
        ax.plot(etas, r, color=_CH[c], lw=1)
        ax.axhline(cls.r_prime[c], color=_CH[c], ls="--", lw=0.8)
    for name, iv in cls.branches.items():
        ax.axvspan(iv.lo, max(iv.hi, iv.lo + 1e-3), color="0.85", zorder=0)
    if sol is not None:
        e1 = sol.choices["eta1"]
        ax.plot([e1], [fgd_for(o, cls.alpha, e1 / cls.context.eta)], "kx", ms=8)
    ax.set_xlabel("eta1")
    ax.set_ylabel("R_{n,n+1} (FGD at normal incidence)")
    ax.set_title(f"1-layer dielectric (eta_n={cls.context.eta:.3g}, alpha={cls.alpha:.3g}); dashed: R' per channel",
                 fontsize=9)


def _panel_conductor(ax, samples: dict, chosen: tuple | None, eta_n: float, title: str) -> None:
    """Figure 4b/c style: kappa against eta along the conductor class, per channel."""
    e, k = samples["eta1"], samples["kappa1"]
    for c in range(3):
        ax.plot(e[:, c], k[:, c], color=_CH[c], lw=1.5)
    if chosen is not None:
        for c in range(3):
            ax.plot([chosen[0][c]], [chosen[1][c]], "x", color=_CH[c], ms=8)
    lim = np.nanmax(e) * 1.1 if np.isfinite(np.nanmax(e)) else 2.0
    ax.plot([0, lim], [0, lim], "k:", lw=0.8, label="kappa = eta")
    ax.set_xlabel("eta (real part)")
    ax.set_ylabel("kappa")
    ax.set_title(title, fontsize=9)


def _panel_dielectric2(ax, cls: TwoLayerClass, sol) -> None:
    """Figures 9b / 11 / 12 style: the class in the (eta1, eta2) plane coloured by tau1, with the
    per-channel tau1 = 0 isolines, the eta_max box and eta_sigma_max."""
    smp = cls.sample(40, 40)
    o = cls.context.options
    if smp.get("eta2") is not None and smp["eta2"].size:
        t = np.max(smp["tau1"], axis=1)
        # tau1 diverges where R'_12 -> 0 (edge of N1): clip the colour scale at the 90th percentile
        vmax = max(float(np.percentile(t, 90)), 1e-6)
        sc = ax.scatter(smp["eta1_of_sample"], smp["eta2"], c=np.minimum(t, vmax), s=6, cmap="viridis", vmin=0,
                        vmax=vmax)
        import matplotlib.pyplot as plt
        plt.colorbar(sc, ax=ax, label="max tau1")
    if smp["eta1"].size:
        for c in range(3):
            ax.plot(smp["eta1"], smp["root_lower"][:, c], color=_CH[c], lw=1)
            ax.plot(smp["eta1"], smp["root_upper"][:, c], color=_CH[c], lw=1)
    ax.add_patch(__import__("matplotlib.patches", fromlist=["Rectangle"]).Rectangle(
        (1, 1), o.eta_max - 1, o.eta_max - 1, fill=False, ls="--", color="0.4"))
    if math.isfinite(cls.eta_sigma_max):
        ax.axvline(cls.eta_sigma_max, color="0.3", ls="-.", lw=1, label="eta_sigma_max")
    for iv in cls.n1:
        ax.axvspan(iv.lo, iv.hi, ymax=0.03, color="k", alpha=0.6)
    if sol is not None:
        ax.plot([sol.choices["eta1"]], [sol.choices["eta2"]], "rx", ms=9, mew=2)
    ax.set_xlim(0.9, o.eta_max + 0.2)
    ax.set_ylim(0.9, o.eta_max + 0.2)
    ax.set_xlabel("eta1 (bar: N1)")
    ax.set_ylabel("eta2")
    ax.set_title(f"2-layer dielectric (tau0={_f(cls.tau0, '.3g')}); lines: tau1 = 0 per channel", fontsize=9)


def _panel_conductor2_eq(ax, cls: TwoLayerClass, sol) -> None:
    """Figure 16 (left) style: eta1 against the equivalent index of the conductor at tau1 = 0
    (the class extends upwards: tau1 > 0 raises the required reflectance)."""
    smp = cls.sample(60, 1)
    if smp["eta1"].size:
        rp = smp["R_prime"]
        for c in range(3):
            s = np.sqrt(np.clip(rp[:, c], 0, 0.999999))
            eq = smp["eta1"] * (1 + s) / (1 - s)
            ax.plot(smp["eta1"], eq, color=_CH[c], lw=1)
            ax.fill_between(smp["eta1"], eq, np.nanmax(eq) * 2, color=_CH[c], alpha=0.07)
    if sol is not None:
        eqs = sol.info.get("eta2_equivalent")
        for c in range(3):
            ax.plot([sol.choices["eta1"]], [eqs[c]], "x", color=_CH[c], ms=8)
    ax.set_xlabel("eta1")
    ax.set_ylabel("equivalent eta2 (tau1 = 0 at the curve)")
    ax.set_title("2-layer conductor: (eta1, equivalent index), section 5.2.4", fontsize=9)


def _panel_tau_slice(ax, cls: TwoLayerClass, sol) -> None:
    """Figure 9c style: tau1 per channel along N2 at the chosen eta1 (eq. 13)."""
    pt = cls.at(sol.choices["eta1"])
    for iv in pt.n2:
        e2 = np.linspace(iv.lo, iv.hi, 120)
        t = np.array([cls.tau1_at(pt, float(e)) for e in e2])
        for c in range(3):
            ax.plot(e2, t[:, c], color=_CH[c], lw=1)
    ax.plot([sol.choices["eta2"]] * 3, sol.choices["tau1"], "kx", ms=7)
    ax.set_xlabel("eta2 (N2 at the chosen eta1)")
    ax.set_ylabel("tau1 (eq. 13)")
    ax.set_title(f"slice eta1 = {sol.choices['eta1']:.4g}", fontsize=9)


def classes_figure(inv: Inversion):
    """One row per lobe with its equivalence class in the context of the lobes chosen above it
    (figures 4, 7, 9, 11, 12 and 16 of the paper, in that spirit); crosses mark the chosen point."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    classes = inv.classes
    n = max(1, len(classes))
    fig, axes = plt.subplots(n, 2, figsize=(11, 3.9 * n), squeeze=False)
    for k, cls in enumerate(classes):
        sol = inv.solutions[k] if k < len(inv.solutions) else None
        a0, a1 = axes[k]
        title = f"lobe {k + 1}: {cls.lobe.describe()}"
        a1.axis("off")
        if not cls.achievable:
            _panel_empty(a0, title, cls.reason)
            continue
        if cls.kind == "dielectric-1":
            _panel_dielectric1(a0, cls, sol)
        elif cls.kind == "conductor-1":
            smp = cls.sample(48)
            chosen = None if sol is None else (np.asarray(sol.choices["eta1"]), np.asarray(sol.info["kappa1"]))
            _panel_conductor(a0, smp, chosen, cls.context.eta,
                             f"1-layer conductor (eta_n={cls.context.eta:.3g}; eqs. 8-10)")
        elif cls.kind == "dielectric-2":
            _panel_dielectric2(a0, cls, sol)
            if sol is not None:
                a1.axis("on")
                _panel_tau_slice(a1, cls, sol)
        else:
            _panel_conductor2_eq(a0, cls, sol)
            if sol is not None:
                a1.axis("on")
                o = cls.context.options
                pt = cls.at(sol.choices["eta1"])
                tgt = pt.r_prime * np.exp(2.0 * np.asarray(sol.choices["tau1"]))
                us = np.linspace(0, 1, 40)
                e = np.full((40, 3), np.nan)
                kk = np.full((40, 3), np.nan)
                for c in range(3):
                    for i, u in enumerate(us):
                        r = conductor_point(o, pt.alpha_lookup[c], tgt[c], pt.eta1, u=float(u))
                        if not isinstance(r, str):
                            e[i, c], kk[i, c] = r[0], r[1]
                _panel_conductor(a1, {"eta1": e, "kappa1": kk},
                                 (np.asarray(sol.choices["eta2"]), np.asarray(sol.info["kappa2"])), pt.eta1,
                                 f"its conductor base at tau1={_f(sol.choices['tau1'], '.3g')}")
        a0.set_title(title + "\n" + a0.get_title(), fontsize=9)
    fig.tight_layout()
    return fig
