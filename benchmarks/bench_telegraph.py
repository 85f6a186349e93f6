"""Telegraph reference pixels on the paper's case: their cost, and what ``telegraph: auto`` saves.

Run: ``python benchmarks/bench_telegraph.py [--size 2048] [--nframes 74] [--realizations 10]
[--fraction 0.05] [--amplitude 25] [--rate 0.015] [--seed 1]``.

The paper's case (as ``spherex-reduce demo`` builds it: 2048², 32 channels,
S = 24, r = 32 distributed reference reads, c = 4, N = 74, every Table 2 term,
raw ramps) is simulated twice per realisation with the same seed: without
telegraph noise, and with ``--fraction`` of the reference pixels telegraph
(``scene: rtn: {pixels: reference}``, step ``--amplitude`` e, switching rate
``--rate`` Hz).  Each is reduced with the shipped ``spherex-default``
(``telegraph: auto``) and with the same pipeline keeping every reference pixel
(``telegraph: keep``, the reduction before telegraph pixels were looked for).

Prints a table of the 5-20' band power of each (mean ± standard error over
realisations, and each one's ratio to the telegraph-free ``keep`` image of the
same realisation), the detection's false alarms (telegraph-free exposures:
every pixel flagged; with telegraph: flagged pixels not telegraph) and misses
(telegraph pixels not flagged; those that never switched during the exposure
counted apart), and the time of the search (`find_telegraph` on the side
block of each raw exposure) against the time of the reduction.
"""

import argparse
import platform
import time

import numpy as np

from spherex_reduce.analysis import run_case
from spherex_reduce.io.sources import side_block
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.reduce.steps.reference.strategies import reference_pixels, reference_rows
from spherex_reduce.reduce.steps.reference.telegraph import find_telegraph
from spherex_reduce.simulation.scene import load_scene
from spherex_reduce.simulation.simulator import TIER_RTN_REFERENCE
from spherex_reduce.simulation.synthesis import rng_for
from spherex_reduce.simulation.telegraph import ReferenceTelegraph


def keep_pipeline():
    """``spherex-default`` with ``telegraph: keep`` in its ``correct_reference``."""
    steps = []
    for step in as_pipeline("spherex-default").config["steps"]:
        (name, params), = step.items()
        if name == "correct_reference":
            params = {**params, "telegraph": "keep"}
        steps.append({name: dict(params or {})})
    return {"name": "spherex-default-keep", "steps": steps}


def scene(size, nframes, rtn=None):
    """The demo's paper case at ``size`` (raw ramps), with ``rtn`` in the scene."""
    nch = max(1, min(32, size // 64))
    sc = {"geometry": {"nrows": size, "ncols": size, "nchannels": nch, "ref_border": 4},
          "readout": {"skip": 24, "ref_reads": 32, "ref_mode": "distributed",
                      "phantom_reads": 4, "nframes": nframes},
          "output": {"mode": "ramps"}}
    if rtn:
        sc["scene"] = {"rtn": rtn}
    return sc


def truth(sc, seed):
    """The simulated telegraph pixels ``{(row, column)}`` of the reference rows read (what
    the correction uses; side columns are not), and those among them that never switched
    during the exposure."""
    s = load_scene(sc).schedule
    r = sc["scene"]["rtn"]
    tel = ReferenceTelegraph(s, r["fraction"], r["amplitude"], r["rate"],
                             rng_for((seed, ()), TIER_RTN_REFERENCE))
    states = np.array([tel.frame(k)[1] for k in range(s.nframes)])  # (frames, slots)
    # the slots come pixel by pixel, one per read of the pixel's row
    reads_per_row = np.bincount(s.rows, minlength=s.geometry.nrows)
    pixel = np.repeat(np.arange(tel.rows.size), reads_per_row[tel.rows])
    still = set()
    for p in range(tel.rows.size):
        v = states[:, pixel == p]
        if v.size and v.min() == v.max():
            still.add((int(tel.rows[p]), int(tel.columns[p])))
    used = np.isin(tel.rows, s.rows[s.is_reference])  # what the correction reads
    return ({(int(r_), int(c)) for r_, c in zip(tel.rows[used], tel.columns[used], strict=True)},
            {p for p in still if p[0] in set(s.rows[s.is_reference].tolist())})


def flagged(reduced):
    t = reduced.tables["REFTELEG"]
    return {(int(r), int(c)) for r, c in zip(t["row"], t["column"], strict=True)}


def search_seconds(raw):
    side = side_block(raw)
    s = raw.schedule
    values = reference_pixels(side, s)
    rows = reference_rows(side, s)
    t0 = time.perf_counter()
    find_telegraph(values, rows, s.geometry)
    return time.perf_counter() - t0


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--nframes", type=int, default=74)
    ap.add_argument("--realizations", type=int, default=10)
    ap.add_argument("--fraction", type=float, default=0.05)
    ap.add_argument("--amplitude", type=float, default=25.0, help="telegraph step (e)")
    ap.add_argument("--rate", type=float, default=0.015, help="switching rate (Hz)")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args(argv)
    rtn = {"fraction": args.fraction, "amplitude": args.amplitude, "rate": args.rate,
           "pixels": "reference"}
    pipes = {"keep": as_pipeline(keep_pipeline()), "auto": as_pipeline("spherex-default")}
    bp = {(tel, lab): [] for tel in (False, True) for lab in pipes}
    false_free = false_tel = hits = misses = still_missed = n_true = n_still = 0
    tested = []
    search, reduce_s = [], {lab: [] for lab in pipes}
    for i in range(args.realizations):
        seed = args.seed + i
        for tel in (False, True):
            sc = scene(args.size, args.nframes, rtn if tel else None)
            res = run_case(sc, pipes, {}, seed=seed, keep=True)
            for lab in pipes:
                bp[tel, lab].append(res.measured[lab]["band_power"].value)
                reduce_s[lab].append(res.reduce_seconds[lab])
            found = flagged(res.reduced["auto"])
            tested.append(res.reduced["auto"].tables["REFTELEG"].meta["tested"])
            search.append(search_seconds(res.raw))
            if not tel:
                false_free += len(found)
                continue
            true, still = truth(sc, seed)
            n_true += len(true)
            n_still += len(still)
            false_tel += len(found - true)
            hits += len(found & true)
            misses += len((true - still) - found)
            still_missed += len(still - found)
            del res
    ref = np.array(bp[False, "keep"])
    print(f"# bench_telegraph: {args.size}² ({max(1, min(32, args.size // 64))} channels), "
          f"N = {args.nframes}, {args.realizations} realisation(s) from seed {args.seed}; "
          f"telegraph: {args.fraction:g} of the reference pixels, step {args.amplitude:g} e, "
          f"rate {args.rate:g} Hz; {platform.node()}, {time.strftime('%Y-%m-%d %H:%M')}")
    print()
    print("| exposure | reduction | 5-20' band power (e/s)² pix² | ratio to telegraph-free keep |")
    print("|---|---|---|---|")
    for tel in (False, True):
        for lab in ("keep", "auto"):
            v = np.array(bp[tel, lab])
            ratio = v / ref
            err = v.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else float("nan")
            rerr = ratio.std(ddof=1) / np.sqrt(v.size) if v.size > 1 else float("nan")
            print(f"| {'telegraph' if tel else 'telegraph-free'} | {lab} | "
                  f"{v.mean():.5g} ± {err:.2g} | {ratio.mean():.4f} ± {rerr:.4f} |")
    free_tested = int(np.sum(tested[0::2]))
    print()
    print("| detection | value |")
    print("|---|---|")
    print(f"| pixels tested per exposure | {np.mean(tested):.0f} |")
    print(f"| false alarms, telegraph-free exposures | {false_free} of {free_tested} "
          f"({false_free / max(free_tested, 1):.2g}) |")
    print(f"| false alarms, telegraph exposures | {false_tel} |")
    print(f"| telegraph pixels found | {hits} of {n_true} |")
    print(f"| missed (switched at least once) | {misses} of {n_true - n_still} "
          f"({misses / max(n_true - n_still, 1):.2g}) |")
    print(f"| never switched in the exposure (missed / all) | {still_missed} / {n_still} |")
    print(f"| search time (find_telegraph on the side block) | {np.median(search):.3f} s "
          f"median (max {np.max(search):.3f}) |")
    for lab in ("keep", "auto"):
        print(f"| reduction time, {lab} | {np.median(reduce_s[lab]):.2f} s median |")


if __name__ == "__main__":
    main()
