"""``whitted diff A B``: two images you already have, judged by the gate's rules (idiff's job).

    whitted diff A B [--rule exact|converged] [--threshold NAME=VALUE]... [--warn NAME=VALUE]...
                     [--json FILE|-] [--junit FILE] [--report DIR] [--diff FILE] [--force]

A is the image under test (ours), B the reference (the golden): relative errors are relative
to B. Each is an OpenEXR (linear RGB, as ``whitted render`` and the goldens write them) or a
PNG (8- or 16-bit sRGB, decoded to linear), in either order. The rule is the one ``whitted
check`` applies (``evaluation.gate.rules``, with its default thresholds; ``--threshold``
replaces one, as a scene's ``[check.<rule>]`` does): **exact**, every pixel within
``max_rel`` of B and the mean within ``mean_rel``; images alone carry no tie probe, so no
pixel is excused. **converged**, the t-test of A's mean and variance against B's: both must
be converged goldens (a ``var`` layer and a batch count in their metadata or sidecar).

Prints the verdict line ``check`` prints (PASS, WARN, FAIL, SIZE) and, when it is not PASS,
the metadata fields that differ (``evaluation.gate.imagemeta``: renderer, scene key, spp,
max depth, shading, mode, backend, precision), then the summary; exits with the verdict's
code. ``--json`` / ``--junit`` / ``--report`` are check's, refused over a file this tool did
not write unless ``--force``; ``--diff FILE`` writes the difference image (``.exr``: |A - B|
linear; ``.png``: the same scaled so the largest difference is white), never over an
existing file unless ``--force``. A missing or unreadable file, or one that is not an EXR
or PNG, is one error line and exit 4, as is a reference B with NaN or infinite pixels; NaN
or infinite pixels in A fail it (exit 2).
"""
from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from evaluation.gate import verdict as vd
from evaluation.gate.imagemeta import differences, format_differences, image_metadata
from evaluation.gate.rules import THRESHOLDS, Batches
from renderer.film import EXR_MAGIC, PNG_MAGIC, read_exr_layers, read_png
from renderer.outputs import check_output_file
from renderer.scene import SceneError

from .check import check_outputs, write_outputs
from .options import EXIT, EXIT_CODE_HELP, CliError


def register(subparsers) -> None:
    """Add the ``diff`` subcommand to the main CLI's subparsers."""
    p = subparsers.add_parser(
        "diff", help="two images (EXR or PNG) judged by check's rules: verdict and exit code",
        description=__doc__.split("\n\n", 1)[0].replace("``", "") + "\n\n"
        + __doc__.split("\n\n", 2)[2].replace("``", "").replace("**", ""),
        epilog=EXIT_CODE_HELP, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("a", type=Path, metavar="A", help="the image under test (EXR or PNG)")
    p.add_argument("b", type=Path, metavar="B", help="the reference image (EXR or PNG)")
    p.add_argument("--rule", default="exact", choices=tuple(THRESHOLDS),
                   help="the comparison (default exact)")
    p.add_argument("--threshold", action="append", default=[], metavar="NAME=VALUE",
                   help="replace one threshold of the rule (repeatable): exact "
                        f"{', '.join(THRESHOLDS['exact'])}; converged "
                        f"{', '.join(THRESHOLDS['converged'])}")
    p.add_argument("--warn", action="append", default=[], metavar="NAME=VALUE",
                   help="WARN (exit 1) when a number the rule reports exceeds VALUE "
                        "(repeatable; as a scene's [check.warn])")
    p.add_argument("--json", metavar="FILE|-", help="write the verdict as JSON ('-': stdout)")
    p.add_argument("--junit", type=Path, metavar="FILE", help="write JUnit XML")
    p.add_argument("--report", type=Path, metavar="DIR",
                   help="write the HTML report (both images, |diff|, FLIP) into DIR")
    p.add_argument("--diff", type=Path, metavar="FILE", dest="diff_image",
                   help="write the difference image: .exr |A - B| linear, .png scaled to "
                        "its largest difference")
    p.add_argument("--force", action="store_true",
                   help="replace an existing --report folder or --diff file, or a --json / "
                        "--junit file that is not a report of this tool")
    p.add_argument("--quiet", action="store_true", help="print only the summary line")
    p.set_defaults(func=cmd_diff)


# ---- reading -------------------------------------------------------------------------------
def read_image(path: Path, which: str) -> tuple[np.ndarray, np.ndarray | None]:
    """(linear RGB float32 (H, W, 3), the ``var`` layer or None) of an EXR or PNG file;
    ``CliError`` (exit 4, one line naming the file) for anything else."""
    try:
        if path.is_dir():
            raise CliError(f"{which} {path}: is a folder, not an image", code=EXIT["file"])
        with open(path, "rb") as f:
            magic = f.read(8)
        if magic[:4] == EXR_MAGIC:
            layers = read_exr_layers(path)
            return layers[""], layers.get("var")
        if magic == PNG_MAGIC:
            return read_png(path), None
    except FileNotFoundError:
        raise CliError(f"{which} {path}: no such file", code=EXIT["file"]) from None
    except (OSError, ValueError) as e:
        text = str(e) if str(path) in str(e) else f"{path}: {e}"
        raise CliError(f"{which} {text}", code=EXIT["file"]) from None
    shown = "empty" if not magic else f"starts with {magic[:4]!r}"
    raise CliError(f"{which} {path}: not an EXR or PNG image ({shown})", code=EXIT["file"])


def _pairs(values, flag: str) -> dict:
    out = {}
    for item in values:
        name, sep, text = item.partition("=")
        if not sep or not name:
            raise CliError(f"{flag} {item}: expected NAME=VALUE")
        try:
            value = int(text) if text.strip().lstrip("-").isdigit() else float(text)
        except ValueError:
            raise CliError(f"{flag} {item}: {text!r} is not a number") from None
        out[name.strip()] = value
    return out


def _non_finite(image: np.ndarray) -> np.ndarray:
    return np.argwhere(~np.isfinite(image).all(axis=-1))


def _batches(image, var, meta: dict, which: str, path: Path) -> Batches:
    n = meta.get("batches")
    if var is None or n is None:
        raise CliError(f"{which} {path}: the converged rule needs a converged golden (a var "
                       "layer and a batch count in its metadata or sidecar)")
    return Batches(np.asarray(image, np.float64), np.asarray(var, np.float64), int(n))


# ---- the command ---------------------------------------------------------------------------
def cmd_diff(args: argparse.Namespace) -> int:
    from reference.golden import Golden

    out = sys.stderr if args.json == "-" else sys.stdout
    why = "set by --threshold on the command line"
    try:
        th = vd.threshold_values(args.rule, _pairs(args.threshold, "--threshold"), why=why,
                                 where=lambda name: f"--threshold {name}")
    except ValueError as e:
        raise CliError(str(e)) from None
    warn = _pairs(args.warn, "--warn")
    check_outputs(args)
    if args.diff_image is not None:
        if args.diff_image.suffix.lower() not in (".exr", ".png"):
            raise CliError(f"--diff {args.diff_image}: expected a .exr or .png file name")
        try:
            check_output_file(args.diff_image, overwrite=args.force, flag="--force")
        except OSError as e:
            raise CliError(f"--diff {e}", code=EXIT["file"]) from e

    t0 = time.perf_counter()
    a, a_var = read_image(args.a, "A")
    b, b_var = read_image(args.b, "B")
    meta_a, meta_b = _metadata(args.a), _metadata(args.b)
    bad_b = _non_finite(b)
    if len(bad_b):
        raise CliError(f"B {args.b}: {len(bad_b):,} pixels are NaN or infinite (first at "
                       f"{tuple(int(i) for i in bad_b[0])}): not a usable reference",
                       code=EXIT["file"])
    v = vd.Verdict(args.a.stem, str(args.a), 0, meta_a.get("view", "-"),
                   meta_a.get("shading", "-"), args.rule, "ERROR", "",
                   thresholds=vd._threshold_rows(th, THRESHOLDS[args.rule]), golden=str(args.b),
                   label=f"{args.a} vs {args.b} ({args.rule})")
    v.metadata = {"ours": meta_a, "golden": meta_b}
    v.differences = differences(meta_a, meta_b)
    bad_a = _non_finite(a)
    if len(bad_a) and a.shape == b.shape:
        v.status = "FAIL"
        v.reason = (f"{len(bad_a):,} pixels of A are NaN or infinite ("
                    + ", ".join(f"({y},{x})" for y, x in bad_a[:5].tolist())
                    + (", ..." if len(bad_a) > 5 else "") + ")")
    else:
        if args.rule == "converged":
            ours = _batches(a, a_var, meta_a, "A", args.a)
            ref = Golden(b, b_var, {"batches": _batches(b, b_var, meta_b, "B", args.b).n},
                         args.b)
        else:
            ours, ref = a, Golden(b, None, {}, args.b)
        try:
            v.status, v.reason, v.excused, v.result = vd.judge(ours, ref, args.rule, th, warn)
        except SceneError as e:
            raise CliError(f"--warn: {e}") from None
        if v.status == "SIZE":
            v.reason = (f"A is {a.shape[1]}x{a.shape[0]}, B {b.shape[1]}x{b.shape[0]}")
    v.seconds = time.perf_counter() - t0
    if a.shape == b.shape:
        v.ours, v.ref = a, b
    if not args.quiet:
        print(vd.format_line(v), file=out)
        if v.status != "PASS" and v.differences:
            print(format_differences(v.differences), file=out)
    print(vd.summary_line([v]), file=out)
    if args.diff_image is not None and a.shape == b.shape:
        _write_difference(args.diff_image, a, b, args.force)
        print(f"difference: {args.diff_image}", file=out)
    write_outputs(args, [v], title=f"whitted diff: {args.a} vs {args.b}")
    return v.exit_code


def _metadata(path: Path) -> dict:
    try:
        return image_metadata(path)
    except (OSError, ValueError):
        return {}


def _write_difference(path: Path, a, b, force: bool) -> None:
    from evaluation.gate.artifacts import difference, difference_png, save_png
    from renderer.film import write_exr

    if path.suffix.lower() == ".exr":
        write_exr(path, difference(a, b), overwrite=force)
    else:
        save_png(path, difference_png(a, b)[0], overwrite=force)
