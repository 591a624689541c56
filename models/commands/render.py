"""``gonio render``: the reference of a simulated file and the models on a lit sphere, one PNG
(:mod:`models.render`; ``docs/render.md``); ``--stokes``: a polarized file's degree and angle of
linear polarization on the sphere (:mod:`models.render.stokes`)."""

from __future__ import annotations

import argparse
import json

from goniometer.cli.common import UsageError, add_overwrite, output_path, whole_number


def register(sub) -> None:
    """Add ``render`` to the ``gonio`` sub-command parser."""
    p = sub.add_parser("render", help="render the reference (and models) on a sphere lit by one directional light")
    p.add_argument("file", metavar="FILE.h5", help="a slices file (gonio simulate) or a tabulated file (gonio tabulate)")
    p.add_argument("--out", required=True, metavar="sphere.png", help="the PNG to write")
    p.add_argument("--model", action="append", metavar="NAME",
                   help="a model to render beside the reference (repeatable; 'all': every model that supports "
                        "the stack; default: the reference alone)")
    p.add_argument("--light-angle", dest="light_angle", default="30", metavar="DEG",
                   help="angle between the light and the view direction, degrees in [0, 90] (default 30)")
    p.add_argument("--size", default="512", metavar="PX", help="sphere diameter in pixels, in [16, 4096] (default 512)")
    p.add_argument("--stokes", action="store_true",
                   help="a polarized file's degree and angle of linear polarization on the sphere for unpolarized "
                        "light, in the camera's frame (the PNG then holds them instead of the models; default: the "
                        "radiance comparison)")
    p.add_argument("--json", action="store_true", help="print the exposure and each model's image RMSE as JSON "
                                                       "(with --stokes: the polarization's summary)")
    add_overwrite(p)
    p.set_defaults(func=cmd_render)


def _number(text: str, flag: str, kind: type, allowed: str):
    try:
        return whole_number(text) if kind is int else kind(text)
    except (ValueError, TypeError, argparse.ArgumentTypeError):
        raise UsageError(f"{flag}: {text!r} is not {'an integer' if kind is int else 'a number'} ({allowed})") from None


def cmd_render(args: argparse.Namespace) -> int:
    from goniometer.files import slices as store
    from models.base import ModelError
    from models.commands.failures import report_failures
    from models.registry import UnknownModel
    from models.render import RenderError, SphereView, model_names, render_file

    angle = _number(args.light_angle, "--light-angle", float, "degrees in [0, 90]")
    size = _number(args.size, "--size", int, "pixels in [16, 4096]")
    try:
        SphereView(size, angle)
    except RenderError as e:
        flag = "--size" if str(e).startswith("size") else "--light-angle"
        raise UsageError(f"{flag}: {str(e).split(': ', 1)[1]}") from None
    if args.stokes:
        if args.model:
            raise UsageError("--stokes: draws the reference's polarization alone; drop --model (models are "
                             "compared on the radiance sphere without --stokes)")
        return _stokes(args, angle, size)
    output_path(args.out, inputs=[args.file], overwrite=args.overwrite)
    try:
        model_names(args.model)
        spheres = render_file(args.file, args.out, args.model, angle, size)
    except (ModelError, RenderError, store.StoreError) as e:
        msg = str(e)
        raise UsageError(msg if msg.startswith(str(args.file)) or msg.startswith(str(args.out))
                         or isinstance(e, UnknownModel) else f"{args.file}: {msg}") from None
    doc = spheres.to_json()
    if args.json:
        print(json.dumps({**doc, "out": str(args.out)}, indent=2))
        return report_failures(doc["failed"])
    print(f"{doc['material']}: {doc['side'].upper()} sphere, {doc['size']} px, light at {doc['light_angle_deg']:g} deg; "
          f"reference: {doc['reference']}")
    if doc["no_value_fraction"] > 0:
        print(f"reference has no value on {doc['no_value_fraction']:.1%} of the sphere (hatched)")
    for name, m in doc["models"].items():
        rmse = "-" if m["rmse"] is None else f"{m['rmse']:.4g}"
        print(f"  {name:16s} image RMSE {rmse} (display units, white = 1)")
    for name, reason in doc["skipped"].items():
        print(f"skipped {name}: {reason}")
    print(f"wrote {args.out}")
    return report_failures(doc["failed"])


def _stokes(args: argparse.Namespace, angle: float, size: int) -> int:
    """``gonio render --stokes``: refused in one line for a file without Mueller matrices."""
    from goniometer.files import slices as store
    from models.render import RenderError
    from models.render.stokes import NotPolarized, render_stokes_file

    output_path(args.out, inputs=[args.file], overwrite=args.overwrite)
    try:
        sphere = render_stokes_file(args.file, args.out, angle, size)
    except NotPolarized as e:
        raise UsageError(f"--stokes: {e}") from None
    except (RenderError, store.StoreError) as e:
        raise UsageError(str(e) if str(e).startswith(str(args.file)) else f"{args.file}: {e}") from None
    doc = sphere.to_json()
    if args.json:
        print(json.dumps({**doc, "out": str(args.out)}, indent=2))
        return 0
    median = "-" if doc["dolp_median"] is None else f"{doc['dolp_median']:.3g}"
    print(f"{doc['material']}: {doc['side'].upper()} sphere, {doc['size']} px, light at "
          f"{doc['light_angle_deg']:g} deg; polarization for unpolarized light on {doc['shown_fraction']:.1%} "
          f"of the sphere, DOLP median {median}")
    print(f"({doc['frame']}; {doc['signal_rule']})")
    print(f"wrote {args.out}")
    return 0
