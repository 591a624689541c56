"""A Mitsuba 3 render of an exported RGL file beside ``gonio render``'s sphere of the same material
(``docs/rgl-format.md`` section 9): ``docs/figures/rgl-render.png`` and the numbers of their difference.

The material is ``configs/examples/metal.toml`` (a coated metal). It is simulated twice: on the RGL
grid (exported to ``*_rgb.bsdf``, rendered by Mitsuba's ``measured`` plugin in ``scalar_rgb``: a unit
sphere, an orthographic camera on +z, one directional light at ``--light-angle`` from the view
direction above the camera, the direct-lighting integrator, ``--spp`` samples per pixel) and as
classic slices (rendered by ``models.render``, docs/render.md: one sample at each pixel centre,
the slices interpolated between incident directions). The sphere, the light and the exposure are
the same; the difference image is linear radiance relative to the 99th percentile of ours.

Usage: python benchmarks/rgl_render.py [--rays N] [--size PX] [--spp N] [--light-angle DEG] [--out PNG]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def mitsuba_sphere(bsdf_path: Path, size: int, spp: int, angle_deg: float) -> np.ndarray:
    """(size, size, 3) linear radiance of Mitsuba 3's render (image rows top to bottom)."""
    import mitsuba as mi
    mi.set_variant("scalar_rgb")
    a = np.radians(angle_deg)
    light = np.array([0.0, np.sin(a), np.cos(a)])
    scene = mi.load_dict({
        "type": "scene",
        "integrator": {"type": "direct", "emitter_samples": 1, "bsdf_samples": 0},
        "sensor": {"type": "orthographic",
                   "to_world": mi.ScalarTransform4f().look_at(origin=[0, 0, 5], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": size, "height": size, "rfilter": {"type": "box"},
                            "pixel_format": "rgb"},
                   "sampler": {"type": "independent", "sample_count": spp}},
        "sphere": {"type": "sphere", "radius": 1.0,
                   "bsdf": {"type": "measured", "filename": str(bsdf_path)}},
        "light": {"type": "directional", "direction": (-light).tolist(), "irradiance": {"type": "rgb", "value": 1.0}},
    })
    # the orthographic film spans [-1, 1]^2 at unit scale, rows from +y down: our square; the scene
    # is symmetric under x -> -x, so the film's x orientation does not matter
    return np.array(mi.render(scene))[..., :3]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rays", type=int, default=2_000_000, help="rays per incident direction (default 2,000,000)")
    ap.add_argument("--size", type=int, default=160, help="sphere diameter in pixels (default 160)")
    ap.add_argument("--spp", type=int, default=64, help="Mitsuba samples per pixel (default 64)")
    ap.add_argument("--light-angle", type=float, default=30.0, help="degrees from the view direction (default 30)")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "figures" / "rgl-render.png")
    args = ap.parse_args()

    import goniometer as g
    from goniometer.grids.rgl import grid_for
    from matplotlib.figure import Figure
    from models.render import SphereView, slices_reference
    from models.render.tonemap import display, exposure

    stack = g.load_stack(ROOT / "configs" / "examples" / "metal.toml")
    grid = grid_for(stack)
    print(f"simulating {stack.name} on the RGL grid {len(grid.theta_i_deg)}x1x{grid.n} and as classic slices "
          f"({args.rays:,} rays per incident direction)", file=sys.stderr)
    rgl = g.simulate(stack, g.SimulationSettings.on_rgl_grid(grid, rays=args.rays))
    classic = g.simulate(stack, g.SimulationSettings(rays=args.rays, parametrization="half"))
    with tempfile.TemporaryDirectory() as d:
        path = g.export_rgl(rgl, Path(d) / "metal_rgb.bsdf")
        ours_mi = mitsuba_sphere(path, args.size, args.spp, args.light_angle)
    view = SphereView(args.size, args.light_angle)
    ref = slices_reference(classic)
    ours = view.shade(ref.bsdf)
    inside = view.inside & np.all(np.isfinite(ours), axis=-1)
    k = exposure(ours, view.inside)
    scale = float(np.percentile(np.max(ours[inside], axis=-1), 99))
    diff = np.where(inside[..., None], (ours_mi - np.nan_to_num(ours)) / scale, np.nan)
    lit = inside & (np.max(np.nan_to_num(ours), axis=-1) > 0.01 * scale)
    rel_rmse = float(np.sqrt(np.nanmean(diff[lit] ** 2)))
    mean_ratio = float(np.sum(ours_mi[lit]) / np.sum(ours[lit]))
    print(f"Mitsuba 3 measured ({args.spp} spp) vs gonio render ({args.size} px, light at {args.light_angle:g} deg): "
          f"RMSE {rel_rmse:.4f} of the 99th-percentile radiance over the lit sphere, total radiance ratio "
          f"{mean_ratio:.4f}")

    fig = Figure(figsize=(9.6, 3.4), dpi=110, layout="constrained")
    axes = fig.subplots(1, 3)
    for ax, img, title in ((axes[0], ours, "gonio render (classic slices)"),
                           (axes[1], ours_mi, f"Mitsuba 3 measured, {args.spp} spp")):
        shown = display(np.where(view.inside[..., None], img, np.nan), k)
        # grey: no value (outside the disk, or gonio's light beyond the recorded incident range)
        ax.imshow(np.where(np.isfinite(shown), shown, 0.35), interpolation="nearest")
        ax.set_title(title, fontsize=9)
        ax.set_axis_off()
    lim = max(0.05, float(np.nanpercentile(np.abs(diff), 99)))
    im = axes[2].imshow(diff.mean(axis=-1), cmap="RdBu_r", vmin=-lim, vmax=lim, interpolation="nearest")
    axes[2].set_title(f"Mitsuba - gonio (RGB mean), RMSE {rel_rmse:.3f}", fontsize=9)
    axes[2].set_axis_off()
    fig.colorbar(im, ax=axes[2], shrink=0.8, label="radiance / 99th percentile of gonio's")
    fig.suptitle(f"{stack.name}: the exported RGL file in Mitsuba 3 beside gonio render "
                 f"(light {args.light_angle:g} deg from the view, same exposure; grey: no value)", fontsize=10)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
