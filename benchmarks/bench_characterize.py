"""``characterize`` on darks of our simulator: every term against the injected truth.

Run: ``python benchmarks/bench_characterize.py [--case paper|sidecar] [--pulls] [--size 2048]
[--nframes 74] [--darks 4] [--seeds 20] [--first-seed 0] [--phantom-reads 4] [--scale 1]
[--frame-time T] [--realised]``.

``--case sidecar`` is a JWST-like SIDECAR detector instead of the paper's: 4 outputs
(``--size``/4 columns each), no phantom reads, white noise of 10 e per read,
correlated (common) and uncorrelated (per output) 1/f noise, ACN, a dark current of
0.5 e/s and 2 % telegraph pixels (steps of 150 e at 0.05 Hz), one detector
(``scene.population_seed``: the seed) read ``--darks`` times per seed; the per-pixel
terms (telegraph fraction, step and rate, dark current) are compared too.
``--pulls`` prints, per parameter, the number of seeds, the mean and the standard
deviation of the pulls (fit − truth)/error and the fraction beyond 3, instead of the
table of the first seed.  ``--realised`` (SIDECAR case) simulates each seed's darks again
with the telegraph pixels alone (same seeds: the same flips, no other noise) and adds two
rows: the pull of the rate the population's flips realised against the injected one (what
any fit of those darks sees), and the fit's pull against the realised rate (what the fit
adds); both in the fit's error.

The paper's readout (S = 24, r = 32 distributed, ``--phantom-reads`` c, N =
``--nframes``; ``--size`` rows and columns, 64 columns per channel) with every
Table 2 component, its 1/f and 1/f^1.3 coefficients times ``--scale``, and
ACN, is simulated as raw ramps ``--darks`` times per seed, characterised, and
each component of the model compared with the truth Table 2 gives it (see
``tests/analysis/characterize/test_characterize.py``).  Prints, per term: the
truth, the fitted value and its jackknife error of the first seed, and the mean
and standard deviation of the pulls over ``--seeds`` seeds; then the time and
the peak memory of the process (the darks are simulated one at a time and
passed to ``characterize`` as an iterator, so one dark is in memory at once).

Our simulator draws a both-visible component as one realisation for the
pixels and the phantom reads at every frequency
(``spherex_reduce.simulation.pixel_fast_tier``), so the split between the
``*_both`` and ``*_phantom`` / pixels-only components comes back unbiased here
(before issue 33's fix the part above ``f_B/2`` was drawn independently for
each, and those terms' pulls were -4.3 and +2.3; ``benchmarks/README.md``).
"""

import argparse
import copy
import platform
import resource
import time

import numpy as np
from scipy.optimize import brentq

from spherex_reduce.analysis.characterize import characterize
from spherex_reduce.analysis.pixel_terms import dark_ramps
from spherex_reduce.simulation import simulate

TABLE2 = {"video8": (3.71e-5, 8.4e-3, 0.0, "channel", "both"),
          "roic": (1.97e-3, 0.0, 0.1, "channel", "pixels"),
          "bias_correlated": (0.0, 8.8e-5, 0.0, "common", "both"),
          "bias_phantom_only": (0.0, 3.64e-6, 0.0, "common", "phantom"),
          "bias_pixels_only": (2.91e-6, 3.07e-7, 0.0, "common", "pixels")}


def truth(scale, phantom):
    t = {k: np.array(v[:3]) * [1, scale, scale] for k, v in TABLE2.items()}
    if not phantom:
        return {"channel": t["video8"] + t["roic"],
                "common": t["bias_correlated"] + t["bias_pixels_only"]}
    return {"channel": t["roic"] + [t["video8"][0], 0, 0],
            "channel_both": t["video8"] * [0, 1, 1],
            "channel_phantom": t["video8"] * [1, 0, 0],
            "common": t["bias_pixels_only"],
            "common_both": t["bias_correlated"],
            "common_phantom": t["bias_phantom_only"]}


#: The SIDECAR case: white (e²/Hz: 10 e per read at 100 kHz), 1/f of each output with ACN,
#: 1/f common to the outputs (e²); telegraph pixels and dark current.
SIDECAR = {"white": 2e-3, "channel_beta": 2e-2, "common_beta": 1e-2}
SIDECAR_PIXELS = {"dark_current": 0.5, "telegraph_fraction": 0.02,
                  "telegraph_amplitude": 150.0, "telegraph_rate": 0.05}


def sidecar_truth(args):
    return {"channel": np.array([SIDECAR["white"], SIDECAR["channel_beta"] * args.scale, 0]),
            "common": np.array([0.0, SIDECAR["common_beta"] * args.scale, 0])}


def telegraph_power(terms):
    """``(value, error)`` of the telegraph population's fraction times squared step that the
    model holds: the pixels found jump by jump (fraction x mean step², their errors
    propagated as independent; the steps' spread left out: the benchmark's is 0) plus the
    faint population's power where fitted (a pixel one of whose flips was missed is handed
    to it); None without the first."""
    f, a = (terms.row(f"telegraph_{k}", "active") for k in ("fraction", "amplitude"))
    if f["status"] != "fitted" or a["status"] != "fitted":
        return None
    value = f["value"] * a["value"] ** 2
    var = (a["value"] ** 2 * f["error"]) ** 2 + (2 * f["value"] * a["value"] * a["error"]) ** 2
    faint = terms.row("faint_telegraph_power", "active")
    if faint["status"] == "fitted":
        value += faint["value"]
        var += faint["error"] ** 2
    return value, float(np.sqrt(var))


def with_acn(want):
    """The truth as a model that found ACN states it (no phantom reads): the channel
    component's correlated terms are ACN's (the simulator draws every ACN component's even
    and odd columns apart), its white level stays in ``channel``."""
    corr = np.array([0.0, 1.0, 1.0])
    return {**want, "channel": want["channel"] * (1 - corr), "acn": want["channel"] * corr}


def realised_rate(sc, seed, darks):
    """The telegraph rate (Hz) the population of ``sc`` realised in the darks of ``seed``:
    each dark simulated again with the telegraph pixels alone (the same random streams: the
    same flips), the flips counted over the intervals ``characterize`` measures (read 0 is
    kept aside), the flip probability ``p`` the maximum-likelihood one of the counts of the
    pixels that flipped (a pixel that never flipped cannot be told from one that is not a
    telegraph: the counts are binomial truncated at 1, ``m p / (1 - (1 - p)**m)`` their
    mean), and the rate ``-log(1 - 2 p) / (2 dt)`` as ``pixel_terms`` takes it."""
    alone = copy.deepcopy(sc)
    alone["noise"] = {"components": [{"name": "none", "alpha": 0.0}]}
    alone["scene"]["dark_current"] = 0.0
    flips, intervals, population, dt = 0, 0, False, None
    for k in range(darks):
        ramps, times, _ = dark_ramps(simulate(alone, seed=1000 * seed + k))
        step = np.diff(ramps.value[1:], axis=0)
        flipped = np.abs(step) > 0.5 * SIDECAR_PIXELS["telegraph_amplitude"]
        count = flipped.sum(axis=0)
        population = population | (count > 0)
        flips = flips + count
        intervals += flipped.shape[0]
        dt = float(np.median(np.diff(times.to_value("s"))))
        del ramps, step, flipped
    mean = flips[population].mean()
    m = intervals

    def excess(q):  # the truncated binomial's mean at q, less the counts'
        return m * q / -np.expm1(m * np.log1p(-q)) - mean

    if mean <= 1.0:  # every pixel flipped once: the likelihood's maximum is at p = 0
        return 0.0
    if excess(0.5) <= 0:  # flips at half the intervals or more: faster than the reads
        return np.nan
    p = brentq(excess, 1e-12, 0.5)
    return -np.log1p(-2 * p) / (2 * dt)


def sidecar_scene(args):
    p = SIDECAR_PIXELS
    comps = [{"name": "outputs", "alpha": SIDECAR["white"],
              "beta": SIDECAR["channel_beta"] * args.scale},
             {"name": "correlated", "beta": SIDECAR["common_beta"] * args.scale,
              "scope": "common"}]
    return {"geometry": {"nrows": args.size, "ncols": args.size, "nchannels": 4,
                         "ref_border": 4},
            "readout": {"skip": 1, "ref_reads": 8, "phantom_reads": 0,
                        "nframes": args.nframes},
            "noise": {"components": comps, "acn": True}, "output": {"mode": "ramps"},
            "scene": {"dark_current": p["dark_current"],
                      "rtn": {"fraction": p["telegraph_fraction"],
                              "amplitude": p["telegraph_amplitude"],
                              "rate": p["telegraph_rate"], "pixels": "active"}}}


def scene(args):
    if args.case == "sidecar":
        return sidecar_scene(args)
    comps = [{"name": n, "alpha": a, "beta": b * args.scale, "gamma": g * args.scale}
             for n, (a, b, g, _, _) in TABLE2.items()]
    return {"geometry": {"nrows": args.size, "ncols": args.size,
                         "nchannels": max(1, args.size // 64), "ref_border": 4},
            "readout": {"skip": 24, "ref_reads": 32, "ref_mode": "distributed",
                        "phantom_reads": args.phantom_reads, "nframes": args.nframes},
            "noise": {"components": comps, "acn": True}, "output": {"mode": "ramps"}}


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=2048)
    p.add_argument("--nframes", type=int, default=74)
    p.add_argument("--darks", type=int, default=4)
    p.add_argument("--seeds", type=int, default=20)
    p.add_argument("--first-seed", type=int, default=0,
                   help="the seeds are first-seed, first-seed + 1, ...: another set of seeds "
                   "tells a bias from chance")
    p.add_argument("--phantom-reads", type=int, default=4)
    p.add_argument("--scale", type=float, default=1.0)
    p.add_argument("--case", choices=("paper", "sidecar"), default="paper")
    p.add_argument("--frame-time", type=float, default=None,
                   help="frame time (s; default the readout's own: 10.6 s at 2048² for the "
                   "SIDECAR case, whose telegraph switches at 0.05 Hz)")
    p.add_argument("--realised", action="store_true",
                   help="SIDECAR case: the telegraph rate's pulls against the rate its flips "
                   "realised too (the darks simulated again with the telegraph alone)")
    p.add_argument("--pulls", action="store_true",
                   help="print per parameter the mean and sd of the pulls over the seeds")
    args = p.parse_args()
    if args.realised and (args.case != "sidecar" or not args.pulls):
        p.error("--realised is for the SIDECAR case's pulls: add --case sidecar --pulls")
    if args.case == "sidecar":
        args.phantom_reads = 0
        want = sidecar_truth(args)
    else:
        want = truth(args.scale, args.phantom_reads > 0)
    sc = scene(args)
    if args.frame_time is not None:
        sc["readout"]["frame_time"] = args.frame_time
    pulls, first, timing = {}, None, None
    splits = []  # seeds whose scene holds two white levels (the simulated one has one)
    for seed in range(args.first_seed, args.first_seed + args.seeds):
        t_sim = [0.0]
        if args.case == "sidecar":
            sc["scene"]["population_seed"] = seed  # one detector per seed, read --darks times

        def darks(seed=seed, t_sim=t_sim):  # one at a time: a dark is released once read
            for k in range(args.darks):
                t0 = time.perf_counter()
                dark = simulate(sc, seed=1000 * seed + k)
                t_sim[0] += time.perf_counter() - t0
                yield dark
                del dark  # before the next is simulated

        t0 = time.perf_counter()
        model = characterize(darks(), pixels=args.case == "sidecar")
        t_char = time.perf_counter() - t0 - t_sim[0]
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # GiB (Linux: KiB)
        t_sim = t_sim[0]
        if first is None:
            first, timing = model, (t_sim, t_char, peak)
        truth_now = with_acn(want) if "acn" in model.components else want
        if (model.scene().get("scene") or {}).get("active_read_noise"):
            splits.append(seed)
        for name, est in model.components.items():
            for i, term in enumerate(("alpha", "beta", "gamma")):
                if est.errors[i] > 0:
                    pulls.setdefault((name, term), []).append(
                        (est.values[i] - truth_now[name][i]) / est.errors[i])
        if model.pixel_terms is not None:
            for term, value in SIDECAR_PIXELS.items():
                row = model.pixel_terms.row(term, "active")
                if row["status"] == "fitted" and row["error"] > 0:
                    pulls.setdefault(("pixels", term), []).append(
                        (row["value"] - value) / row["error"])
                    if term == "telegraph_rate" and args.realised:
                        real = realised_rate(sc, seed, args.darks)
                        if np.isfinite(real):  # (NaN: the flips outpaced the reads)
                            pulls.setdefault(("pixels", "telegraph_rate, realised"),
                                             []).append((real - value) / row["error"])
                            pulls.setdefault(("pixels", "telegraph_rate − realised"),
                                             []).append((row["value"] - real) / row["error"])
            total = telegraph_power(model.pixel_terms)
            if total is not None:
                truth_p = SIDECAR_PIXELS["telegraph_fraction"] * SIDECAR_PIXELS[
                    "telegraph_amplitude"] ** 2
                pulls.setdefault(("pixels", "telegraph power, found + faint"), []).append(
                    (total[0] - truth_p) / total[1])
        print(f"seed {seed}: simulate {t_sim:.1f} s, characterize {t_char:.1f} s, "
              f"ACN z = {model.acn['z']:.1f}", flush=True)
    what = (f"Table 2 x {args.scale:g} (beta, gamma), ACN" if args.case == "paper" else
            f"SIDECAR-like (1/f x {args.scale:g}), ACN, 2 % telegraph pixels")
    print(f"\n{platform.node()}: {args.size}², {sc['geometry']['nchannels']} channels, N = "
          f"{args.nframes}, c = {args.phantom_reads}, {args.darks} darks per seed, "
          f"{args.seeds} seeds from {args.first_seed}, {what}\n")
    if args.pulls:
        print("| parameter | seeds | mean pull | sd of pulls | fraction beyond 3 |")
        print("|---|---|---|---|---|")
        for (name, term), x in pulls.items():
            x = np.array(x)
            sd = f"{x.std(ddof=1):.2f}" if x.size > 1 else "-"
            print(f"| {name}.{term} | {x.size} | {x.mean():+.2f} | {sd} | "
                  f"{np.mean(np.abs(x) > 3):.2f} |")
    else:
        truth_first = with_acn(want) if "acn" in first.components else want
        first_seed = f"seed {args.first_seed}"
        print(f"| term | truth | fitted ({first_seed}) | error | pull ({first_seed}) | "
              "pulls: mean ± sd |")
        print("|---|---|---|---|---|---|")
        for (name, term), x in pulls.items():
            if name == "pixels":
                continue
            i = ("alpha", "beta", "gamma").index(term)
            est = first.components[name]
            x = np.array(x)
            sd = f"{x.std(ddof=1):.2f}" if x.size > 1 else "-"
            print(f"| {name}.{term} | {truth_first[name][i]:.3g} | {est.values[i]:.3g} | "
                  f"{est.errors[i]:.2g} | {x[0]:+.2f} | {x.mean():+.2f} ± {sd} |")
    print(f"\ntwo white levels (scene.active_read_noise: the reference pixels read quieter by "
          f"> 3 errors) held for {len(splits)} of {args.seeds} seeds"
          + (f" ({', '.join(map(str, splits))})" if splits else "")
          + "; the simulated darks have one white level")
    t_sim, t_char, peak = timing
    print(f"\ntime (seed {args.first_seed}): simulate {args.darks} darks {t_sim:.1f} s; "
          f"characterize {t_char:.1f} s ({t_char / args.darks:.1f} s per dark, simulation "
          f"excluded); peak memory of the process {peak:.2f} GiB (the darks are simulated and "
          "read one at a time)")


if __name__ == "__main__":
    main()
