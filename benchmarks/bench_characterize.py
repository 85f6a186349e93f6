"""``characterize`` on darks of our simulator: every term against the injected truth.

Run: ``python benchmarks/bench_characterize.py [--size 2048] [--nframes 74] [--darks 4]
[--seeds 20] [--phantom-reads 4] [--scale 1]``.

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

Our simulator draws the part of a both-visible component above ``f_B/2`` (43 Hz
at full size) independently for the pixels and for the phantom means
(``spherex_reduce.simulation.engine``): the split between the ``*_both`` and
``*_phantom`` / pixels-only components is then biased by construction, and
shows here as large pulls of those terms; the test suite checks the split on
darks drawn sample by sample instead.
"""

import argparse
import platform
import resource
import time

import numpy as np

from spherex_reduce.analysis.characterize import characterize
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


def scene(args):
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
    p.add_argument("--phantom-reads", type=int, default=4)
    p.add_argument("--scale", type=float, default=1.0)
    args = p.parse_args()
    want = truth(args.scale, args.phantom_reads > 0)
    sc = scene(args)
    pulls, first, timing = {}, None, None
    for seed in range(args.seeds):
        t_sim = [0.0]

        def darks(seed=seed, t_sim=t_sim):  # one at a time: a dark is released once read
            for k in range(args.darks):
                t0 = time.perf_counter()
                dark = simulate(sc, seed=1000 * seed + k)
                t_sim[0] += time.perf_counter() - t0
                yield dark
                del dark  # before the next is simulated

        t0 = time.perf_counter()
        model = characterize(darks())
        t_char = time.perf_counter() - t0 - t_sim[0]
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # GiB (Linux: KiB)
        t_sim = t_sim[0]
        if first is None:
            first, timing = model, (t_sim, t_char, peak)
        for name, est in model.components.items():
            for i, term in enumerate(("alpha", "beta", "gamma")):
                if est.errors[i] > 0:
                    pulls.setdefault((name, term), []).append(
                        (est.values[i] - want[name][i]) / est.errors[i])
        print(f"seed {seed}: simulate {t_sim:.1f} s, characterize {t_char:.1f} s, "
              f"ACN z = {model.acn['z']:.1f}", flush=True)
    print(f"\n{platform.node()}: {args.size}², {max(1, args.size // 64)} channels, N = "
          f"{args.nframes}, c = {args.phantom_reads}, {args.darks} darks per seed, "
          f"{args.seeds} seeds, Table 2 x {args.scale:g} (beta, gamma), ACN\n")
    print("| term | truth | fitted (seed 0) | error | pull (seed 0) | pulls: mean ± sd |")
    print("|---|---|---|---|---|---|")
    for (name, term), x in pulls.items():
        i = ("alpha", "beta", "gamma").index(term)
        est = first.components[name]
        x = np.array(x)
        sd = f"{x.std(ddof=1):.2f}" if x.size > 1 else "-"
        print(f"| {name}.{term} | {want[name][i]:.3g} | {est.values[i]:.3g} | "
              f"{est.errors[i]:.2g} | {x[0]:+.2f} | {x.mean():+.2f} ± {sd} |")
    t_sim, t_char, peak = timing
    print(f"\ntime (seed 0): simulate {args.darks} darks {t_sim:.1f} s; characterize "
          f"{t_char:.1f} s ({t_char / args.darks:.1f} s per dark, simulation excluded); peak "
          f"memory of the process {peak:.2f} GiB (the darks are simulated and read one at a "
          "time)")


if __name__ == "__main__":
    main()
