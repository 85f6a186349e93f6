"""Judge the correction strategies on the paper's case: residual noise, white floor, sky kept.

Run: ``python benchmarks/bench_compare.py -o DIR [--mode ramps] [--workers N] [--quick]``.

Runs ``compare-strategies`` (`spherex_reduce.analysis.compare_strategies`) on
the paper's case at full size: the default geometry (2048², 32 channels),
the default readout (S = 24, r = 32 distributed, c = 4, N = 74), Table 2's
noise, slopes (``--mode ramps`` simulates and reduces raw ramps), a sky of
rms 0.05 e/s with P(k) ∝ k^-2, 5 realisations, and the pipelines
``spherex-default`` (the paper's reference mean), ``acn``, ``median``,
``fourier`` (the ``fourier_filter`` plugin's strategy), ``destripe`` (the
``destripe`` plugin's step after the paper's reduction) and ``wiener`` (the
shipped config, once it exists).  A pipeline whose config or plugin is not
available is left out with a note.  ``--quick`` runs a small case (256², 4
channels, N = 20, 2 realisations) as a smoke test.

Prints, per pipeline: the 5–20′ noise band power ± its standard error over
realisations, the white floor, the excess over it, the excess relative to
``spherex-default``'s, the sky transfer and the seconds per exposure of the
reduction; writes ``DIR/compare.ecsv`` and ``DIR/compare.png``.
"""

import argparse
import platform
import sys
import time
import warnings
from pathlib import Path

from spherex_reduce import Pipeline
from spherex_reduce.analysis.compare import compare_strategies, format_summary
from spherex_reduce.core.errors import SpherexReduceError

#: The paper's reduction with the ``fourier`` strategy of plugins/fourier_filter:
#: slopes first, then the image's horizontal Fourier axis filtered.
FOURIER = {"name": "fourier", "steps": [
    {"fit_ramp": {"weighting": "uniform"}}, {"unchop": {}}, {"subtract_phantom": {}},
    {"correct_reference": {"strategy": "fourier", "width": 0, "keep_mean": True}},
    {"sigma_clip": {"sigma": 5.0}}]}
#: The paper's reduction, then the ``destripe`` step of plugins/destripe on the slopes.
DESTRIPE = {"name": "destripe", "steps": [
    {"unchop": {}}, {"subtract_phantom": {}},
    {"correct_reference": {"strategy": "mean", "sigma": 3.0, "maxiters": 5}},
    {"fit_ramp": {"weighting": "uniform"}}, {"destripe": {"sigma": 3.0}},
    {"sigma_clip": {"sigma": 5.0}}]}
#: ``wiener`` after the phantom subtraction: only the reference reads are observations
#: (the phantom values are gone), which shows what the phantom values add.
WIENER_SUBTRACTED = {"name": "wiener-after-phantom", "steps": [
    {"unchop": {}}, {"subtract_phantom": {}},
    {"correct_reference": {"strategy": "wiener", "domain": "slopes"}},
    {"fit_ramp": {"weighting": "uniform"}}, {"sigma_clip": {"sigma": 5.0}}]}
#: The paper's reduction without ``subtract_phantom``: under Table 2 each row's phantom value
#: adds more white noise than the drift it removes, which is most of what ``wiener`` gains
#: over ``spherex-default`` (``wiener`` then uses the phantom values or not: see both rows).
MEAN_NO_PHANTOM = {"name": "mean-no-phantom", "steps": [
    {"unchop": {}}, {"correct_reference": {"strategy": "mean", "sigma": 3.0, "maxiters": 5}},
    {"fit_ramp": {"weighting": "uniform"}}, {"sigma_clip": {"sigma": 5.0}}]}
WIENER_IGNORE = {"name": "wiener-phantom-ignored", "steps": [
    {"unchop": {}},
    {"correct_reference": {"strategy": "wiener", "domain": "slopes", "phantom": "ignore"}},
    {"fit_ramp": {"weighting": "uniform"}}, {"sigma_clip": {"sigma": 5.0}}]}
PIPELINES = ["spherex-default", "acn", "median", FOURIER, DESTRIPE, "wiener",
             WIENER_SUBTRACTED, MEAN_NO_PHANTOM, WIENER_IGNORE]
QUICK_SCENE = {"geometry": {"nrows": 256, "ncols": 256, "nchannels": 4},
               "readout": {"nframes": 20}}


def available(pipelines):
    """The pipelines that build here, and a note for each one that does not."""
    keep, notes = [], []
    for p in pipelines:
        name = p if isinstance(p, str) else p["name"]
        try:
            Pipeline(p, source=name) if isinstance(p, dict) else Pipeline.from_yaml(p)
        except (SpherexReduceError, OSError) as exc:
            notes.append(f"left out {name}: {' '.join(str(exc).split())[:160]}")
            continue
        keep.append(p)
    return keep, notes


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", required=True, metavar="DIR",
                        help="directory for compare.ecsv and compare.png (created)")
    parser.add_argument("--mode", choices=("slopes", "ramps"), default="slopes")
    parser.add_argument("--realizations", type=int, default=None)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--scheduler", default=None, help="dask address, or 'serial'")
    parser.add_argument("--quick", action="store_true", help="small smoke-test case")
    parser.add_argument("--overwrite", action="store_true")
    args = parser.parse_args(argv)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    pipes, notes = available(PIPELINES)
    scene = dict(QUICK_SCENE) if args.quick else {}
    scene["output"] = {"mode": args.mode}
    nreal = args.realizations or (2 if args.quick else 5)
    comparison = {"scene": scene, "sky": {"rms": 0.05, "index": -2.0, "seed": 11},
                  "pipelines": pipes, "realizations": nreal, "seed": 2024}
    for note in notes:
        print(note)
    t0 = time.perf_counter()
    res = compare_strategies(comparison, out / "compare.ecsv", plot=out / "compare.png",
                             scheduler=args.scheduler, workers=args.workers,
                             overwrite=args.overwrite, progress=sys.stderr.isatty())
    wall = time.perf_counter() - t0
    case = "quick 256², 4 channels, N = 20" if args.quick else \
        "paper's case 2048², S = 24, r = 32 distributed, c = 4, N = 74"
    print(f"{case}; {args.mode}; {nreal} realisations; sky 0.05 e/s, k^-2; "
          f"{platform.node()}, {wall:.0f} s wall")
    print(format_summary(res.table, reference="spherex-default"))
    print(paired_report(res.table, "spherex-default"))
    if "mean-no-phantom" in set(res.table["pipeline"]):
        print("like for like (the same steps, the strategy swapped):")
        print(paired_report(res.table, "mean-no-phantom"))
    print(f"wrote {out / 'compare.ecsv'} and {out / 'compare.png'}")
    return 0


def paired_report(table, reference):
    """Per pipeline: its excess minus the reference's, realisation by realisation (the same
    noise and sky: a paired difference), the seconds of its first exposure in a worker and
    the median of the others, and for ``wiener`` its excess over the reference's per k bin."""
    import numpy as np

    lines = ["pipeline              excess - reference's (paired)   ratio per realisation"
             "        s first / s median of the rest"]
    ref = table[table["pipeline"] == reference]
    ref_excess = np.asarray(ref["excess"])
    for name in dict.fromkeys(table["pipeline"]):
        rows = table[table["pipeline"] == name]
        d = np.asarray(rows["excess"]) - ref_excess
        se = d.std(ddof=1) / np.sqrt(d.size) if d.size > 1 else float("nan")
        ratio = np.asarray(rows["excess"]) / ref_excess
        sec = np.asarray(rows["seconds"])
        lines.append(f"{name:<20}  {d.mean():+.3e} ± {se:.1e}   "
                     f"{' '.join(f'{r:.2f}' for r in ratio):<28}  "
                     f"{sec.max():.2f} / {np.median(np.sort(sec)[:-1]) if sec.size > 1 else 0:.2f}")
    if "wiener" in set(table["pipeline"]):
        floor = float(table.meta["floor"])
        k = np.asarray(ref["k"][0])
        with np.errstate(invalid="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)  # empty k bins: NaN
            pr = np.nanmean(np.asarray(ref["power"]), axis=0) - floor
            pw = np.nanmean(np.asarray(table[table["pipeline"] == "wiener"]["power"]),
                            axis=0) - floor
        keep = np.isfinite(k) & (pr > 0)
        lines.append("wiener excess / reference's per k bin (rad/pixel):")
        lines.append("  " + "  ".join(f"{ki:.3g}:{r:.2f}" for ki, r in
                                      zip(k[keep], pw[keep] / pr[keep], strict=True)))
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
