"""``characterize`` on our simulator or NGHXRG's cubes, checked on held-out darks (issue 33).

Run: ``python benchmarks/bench_characterize_heldout.py [--size 256] [--nframes 74]
[--darks 256] [--fraction 0.03] [--amplitude 150] [--rate 0.05] [--seed 0]
[--pixel-rate 100000]`` (the defaults: about 4.5 minutes on two cores; 64 held-out pairs,
so that the band power's own error, ~2 %, is well inside the 10 % target: one pair of
256² darks scatters ~15 % about its expectation, and 4 or 16 pairs measured 1.11 and
1.14 of the forecast where 64 measure 1.01), or on NGHXRG's
cubes ``python benchmarks/bench_characterize_heldout.py --nghxrg DIR [--cases
c_pink,all] [--size 512] [--darks 96] [--out /tmp/nghxrg_cubes]`` (below).

The paper's readout (S = 24, r = 32 distributed, 4 phantom reads, N =
``--nframes``; ``--size`` rows and columns, 64 columns per channel) with every
Table 2 component and ACN, a dark current of 0.005 e/s and a population of
slow telegraph pixels among the light-sensitive ones (``scene.rtn``: the
``--fraction`` of them switching between 0 and ``--amplitude`` e at
``--rate`` Hz per state; one detector: the scene's ``population_seed`` is
``--seed``, so every dark has the same telegraph pixels, as a lab's darks of
one array do) is simulated as raw ramps ``--darks`` times.  The
first half is characterised (`characterize`), and `check_model` predicts the
other half, reduced by the paper's pipeline (``spherex-default``): the
slope scatter against N (the difference of two darks over √2, iteratively
5 σ clipped: paper Fig. 12a) from 2 reads to all, within 5 %, and the
5-20′ band power within 10 % (issue 33's targets).  The table also gives the
prediction without the telegraph pixels the fit found (``streams``): their
excess at large N is what the paper saw at N = 74 (~30 %).  At the default
size a telegraph pixel the fit finds that switches during a ramp is beyond the
5 σ clip at large N, so there is no excess; docs/characterize.rst gives a case
with one (``--fraction 0.1 --amplitude 30 --rate 0.3 --pixel-rate 15000``:
steps near the jumps' threshold, which the fit finds as a population,
`spherex_reduce.analysis.faint_telegraph`).

**NGHXRG's cubes** (``--nghxrg DIR [--cases c_pink,all] [--out DIR]``; defaults then
``--size 512 --nframes 10 --darks 96``): the same check on a peer's simulator.  Each
case's cubes are drawn by NGHXRG 2.6 as ``bench_characterize_nghxrg.py`` draws them (its
`cube`, `config` and NGHXRG set-up are imported from there, never a copy; NGHXRG itself
is never committed), kept in ``--out`` and reused by later runs (the header says the
draw).  NGHXRG gives its amplitudes in electrons and writes them unscaled, so the cubes
are read as ADU at 1 e-/ADU (``input: gain: 1``: the per-pixel terms and the forecast
need a gain).  They are reduced by the paper's pipeline less the phantom step (NGHXRG
has no phantom reads): ``unchop``, ``correct_reference`` (``mean`` of the 4 reference
rows at the top and bottom of each channel, per frame), ``fit_ramp`` (uniform) and
``sigma_clip`` (5 σ).  The first half is characterised, the second half (in pairs)
checked at every N from 2 to ``--nframes``; the band power's own error (the pairs'
standard error) is printed beside it.  The column ``no map`` is the prediction from the
streams' white level instead of the read-noise map.
"""

import argparse
import copy
import time
import warnings
from pathlib import Path

import bench_characterize_nghxrg as ngb  # NGHXRG's cubes: drawn and read as that bench does
import numpy as np
from bench_characterize import TABLE2  # the paper's Table 2, as the round trip injects it

from spherex_reduce.analysis.characterize import characterize, check_model
from spherex_reduce.analysis.characterize.predict import predict_scatter
from spherex_reduce.reduce.pipeline import Pipeline
from spherex_reduce.simulation import simulate

#: The pipeline NGHXRG's darks are reduced by: the paper's without the phantom step.
NGHXRG_STEPS = [{"unchop": {}},
                {"correct_reference": {"strategy": "mean", "sigma": 3.0, "maxiters": 5}},
                {"fit_ramp": {"weighting": "uniform"}}, {"sigma_clip": {"sigma": 5.0}}]


def scene(args):
    comps = [{"name": n, "alpha": a, "beta": b, "gamma": g, "scope": s, "visibility": v}
             for n, (a, b, g, s, v) in TABLE2.items()]
    return {"geometry": {"nrows": args.size, "ncols": args.size,
                         "nchannels": max(1, args.size // 64), "ref_border": 4,
                         "pixel_rate": args.pixel_rate},
            "readout": {"skip": 24, "ref_reads": 32, "ref_mode": "distributed",
                        "phantom_reads": 4, "nframes": args.nframes},
            "noise": {"components": comps, "acn": True}, "output": {"mode": "ramps"},
            # one detector: the same telegraph pixels in every dark, as a lab's darks
            "scene": {"dark_current": 0.005, "population_seed": args.seed,
                      "rtn": {"fraction": args.fraction, "amplitude": args.amplitude,
                              "rate": args.rate, "pixels": "active"}}}


def nghxrg_config(size, nframes):
    """``bench_characterize_nghxrg.config`` with a gain (NGHXRG's amplitudes are electrons,
    written unscaled: 1 e-/ADU) and `NGHXRG_STEPS`."""
    cfg = ngb.config(size, nframes)
    cfg["input"] = {**cfg["input"], "gain": 1.0}
    cfg["steps"] = NGHXRG_STEPS
    return cfg


def run_ours(args):
    """Our simulator's darks: the model of the first half against the second half."""
    sc = scene(args)
    half = args.darks // 2

    def darks(seeds):  # one at a time: each is released once read
        for s in seeds:
            yield simulate(sc, seed=args.seed * 1000 + s)

    t0 = time.perf_counter()
    model = characterize(darks(range(half)), "spherex-default")
    t_fit = time.perf_counter() - t0
    table = check_model(model, darks(range(half, args.darks)), "spherex-default")
    tel = table.meta["telegraph"]
    print(f"size {args.size}^2 x {args.nframes} frames, {args.darks} darks ({half} fitted, "
          f"{args.darks - half} held out: {table.meta['pairs']} pairs); frame time "
          f"{model.schedule.frame_time:.4g}")
    print(f"telegraph injected: fraction {args.fraction:g}, amplitude {args.amplitude:g} e, "
          f"rate {args.rate:g} Hz; found: " + (
              "none" if tel is None else ", ".join(f"{k} {v:.4g}" for k, v in tel.items())))
    found = {k: model.pixel_terms.row(f"telegraph_{k}", "active")
             for k in ("fraction", "amplitude", "rate")}
    print("telegraph found jump by jump: " + ", ".join(
        f"{k} {r['value']:.4g} +- {r['error']:.2g} ({r['status']})" for k, r in found.items()))
    faint = table.meta["faint_telegraph"]
    rows = {k: model.pixel_terms.row(f"faint_telegraph_{k}", "active")
            for k in ("power", "rate", "fraction", "amplitude")}
    print("faint telegraph (fitted as a population): " + (
        "none" if faint is None else
        ", ".join(f"{k} {r['value']:.4g} +- {r['error']:.2g}" for k, r in rows.items())))
    # the channel white level: the streams' fit, the scene's (the pixels' white read noise
    # where a faint population is fitted: it is held once, in scene.rtn) and the injected
    seen = [c for c in model.scene()["noise"]["components"]
            if c.get("visibility", "pixels") in ("pixels", "both")]
    truth = sum(a for a, _, _, _, v in TABLE2.values() if v in ("pixels", "both"))
    streams = model.components["channel"]
    print(f"white level the pixels see (e^2/Hz): injected {truth:.5g}; the streams' fit "
          f"{streams.values[0] + sum(c['alpha'] for c in seen if c['name'] != 'channel'):.5g}"
          f" +- {streams.errors[0]:.2g}; the scene's {sum(c['alpha'] for c in seen):.5g}")
    ok = print_table(table)
    last = table[table["quantity"] == "slope_scatter"][-1]
    print(f"telegraph excess at N = {last['frames']}: measured / streams-only prediction "
          f"{last['measured'] / last['predicted_streams'] - 1:+.1%} (the paper: ~+30 % at "
          f"N = 74), with the telegraph terms {last['ratio'] - 1:+.1%}")
    return t_fit, ok


def nghxrg_seed(seed, case, k):
    """NGHXRG's numpy seed of dark ``k`` of ``case`` (apart from the other bench's)."""
    if not 0 <= k < 100_000:
        raise SystemExit("--darks: at most 100000")
    return (seed + 1) * 1_000_000 + 100_000 * list(ngb.CASES).index(case) + k


def run_nghxrg(args, case, module, pca0):
    """NGHXRG's darks of one case: drawn (or kept from an earlier run), the model of the
    first half against the second half."""
    params = {**ngb.DEFAULTS, **ngb.CASES[case]}
    out = Path(args.out)
    t0 = time.perf_counter()
    paths = [str(ngb.cube(module, pca0, args.size, args.nframes, params,
                          nghxrg_seed(args.seed, case, k),
                          out / f"heldout_{case}_{args.size}x{args.nframes}_{args.seed}_{k}.fits"))
             for k in range(args.darks)]
    t_gen = time.perf_counter() - t0
    pipeline = Pipeline(nghxrg_config(args.size, args.nframes))
    half = args.darks // 2
    t0 = time.perf_counter()
    model = characterize(paths[:half], pipeline, exponent=1.3)
    t_fit = time.perf_counter() - t0
    frames = list(range(2, args.nframes + 1))
    table = check_model(model, paths[half:], pipeline, frames=frames)
    streams = copy.copy(model)
    streams.pixel_terms = None  # the prediction from the streams' white level alone
    no_map = predict_scatter(streams, pipeline, frames)["sigma"]
    print(f"\n{case}: " + ", ".join(f"{k} {v:g}" for k, v in params.items())
          + f"; {args.size}^2 x {args.nframes} frames, {args.darks} darks ({half} fitted, "
          f"{args.darks - half} held out: {table.meta['pairs']} pairs), frame time "
          f"{model.schedule.frame_time:.4g}; NGHXRG or cache {t_gen:.0f} s, "
          f"characterize {t_fit:.1f} s")
    ok = print_table(table, no_map)
    band = table[table["quantity"] == "band_power"][0]
    rel = band["error"] / band["measured"]
    print(f"band power's own error {rel:.1%} ({table.meta['pairs']} pairs: one pair "
          f"{rel * np.sqrt(table.meta['pairs']):.0%})")
    return t_fit, ok


def print_table(table, no_map=None):
    """Print the measured and predicted slope scatter and band power; all within target?"""
    print(f"statistic: {table.meta['statistic']}; unit {table.meta['unit']}")
    extra = "" if no_map is None else f" {'no map':>9} {'ratio':>7}"
    print(f"{'quantity':>14} {'N':>4} {'measured':>11} {'error':>9} {'predicted':>11} "
          f"{'ratio':>7} {'streams':>11} {'ratio':>7}{extra} {'target':>7} within")
    ok = True
    scatter = 0
    for r in table[table["quantity"] != "power_spectrum"]:
        no_tel = r["measured"] / r["predicted_streams"]
        more = ""
        if no_map is not None and r["quantity"] == "slope_scatter":
            more = f" {no_map[scatter]:>9.4g} {r['measured'] / no_map[scatter]:>7.4f}"
            scatter += 1
        elif no_map is not None:
            more = f" {'':>9} {'':>7}"
        print(f"{r['quantity']:>14} {r['frames']:>4d} {r['measured']:>11.5g} "
              f"{r['error']:>9.2g} {r['predicted']:>11.5g} {r['ratio']:>7.4f} "
              f"{r['predicted_streams']:>11.5g} {no_tel:>7.4f}{more} {r['target']:>7.0%} "
              f"{'yes' if r['within'] else 'NO'}")
        ok &= bool(r["within"])
    return ok


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, help="rows and columns (256; NGHXRG 512)")
    p.add_argument("--nframes", type=int, help="frames (74; NGHXRG 10)")
    p.add_argument("--darks", type=int, help="darks per case, half fitted (256; NGHXRG 96)")
    p.add_argument("--fraction", type=float, default=0.03)
    p.add_argument("--amplitude", type=float, default=150.0)
    p.add_argument("--rate", type=float, default=0.05)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--pixel-rate", type=float, default=100000.0)
    p.add_argument("--nghxrg", metavar="DIR", help="NGHXRG's cubes instead of ours: a copy "
                   "of its repository (as bench_characterize_nghxrg.py --nghxrg)")
    p.add_argument("--cases", default="c_pink,all", help="NGHXRG's cases")
    p.add_argument("--out", default="/tmp/nghxrg_cubes",
                   help="where NGHXRG's cubes are kept between runs")
    args = p.parse_args()
    peer = args.nghxrg is not None
    for k, ours, theirs in (("size", 256, 512), ("nframes", 74, 10), ("darks", 256, 96)):
        if getattr(args, k) is None:
            setattr(args, k, theirs if peer else ours)
    t0 = time.perf_counter()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if peer:
            d, module, pca0 = ngb.peer(args.nghxrg, args.out)
            print(f"NGHXRG 2.6 ({d}), PCA-zero template {pca0}")
            results = [run_nghxrg(args, case, module, pca0) for case in args.cases.split(",")]
        else:
            results = [run_ours(args)]
    t_all = time.perf_counter() - t0
    print(f"fit {sum(t for t, _ in results):.1f} s, total {t_all:.1f} s; every target met: "
          f"{all(ok for _, ok in results)}")
    np.seterr()


if __name__ == "__main__":
    main()
