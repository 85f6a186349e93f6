"""Snowballs on dark ramps: their halos flagged, ours against stcal's ``expand_large_events``.

    python benchmarks/bench_snowballs.py [--size 256] [--events 40] [--seed 1] [--no-stcal]

A dark of ``size`` x ``size`` pixels, 30 reads of 1.5 s, 10 e read noise, with
``events`` snowballs at random reads: a core of radius 2-4 pixels that takes
2e5 e and saturates (at 1e5 e over the pedestal: flagged SATURATED, as JWST's
saturation step does), and a halo out to 1.8 core radii that takes 8-16 e in
each of the event's read and the next (below any one pixel's threshold).  One
pixel in 400 has a cosmic ray of 30-1000 e too.  Each pipeline's slopes are
scored on the halo pixels (not flagged unusable): the fraction more than 5 sigma0
wrong and their mean error (sigma0: a jump-free ramp's slope sigma); and on the
clean pixels far from any event: the fraction lost and the rms.

Runs, in one process: ours without and with ``large_events``; stcal 1.20's
two-point detection + OLS_C with its defaults and with ``expand_large_events``
(the JWST snowball flagging: a saturated core and its jump ellipse expanded by
2, ``sat_required_snowball``), given the read noise as stcal takes it: that of
the difference of two reads (CDS), 10 sqrt(2) e.  stcal comes with the ``benchmark`` extra.

Targets (after the issue "Jumps you can trust"): the halo pixels more than 5
ERR wrong <= 1 %, their mean error <= 0.1 sigma0, clean pixels lost <= 0.1 %.
The halo pixels more than 5 sigma0 wrong are printed too: a pixel whose ramp is
cut at the event's reads has a slope error larger than sigma0 (two halves of
the ramp: ~2 sigma0), so some 1-3 % of them are > 5 sigma0 from the noise
alone, whoever flags them.
"""

import argparse
import logging
import sys
import time

import numpy as np
from stcal_peer import run_stcal

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, dq

NF, DT, RN = 30, 1.5, 10.0
PEDESTAL, FULL = 1e4, 1e5  # e: where the ramps start, where a read saturates above it


def schedule(n):
    return ReadoutSchedule(DetectorGeometry(n, n, max(1, n // 64), ref_border=0), skip=1,
                           ref_reads=0, ref_mode="none", phantom_reads=0, nframes=NF,
                           frame_time=DT)


def simulate(n, events, rng):
    """The cube (e, float32), its saturation flags, each pixel's role (0 clean, 1 halo, 2
    core, 3 near an event, 4 cosmic ray)."""
    cube = PEDESTAL + rng.normal(0, RN, (NF, n, n))
    role = np.zeros((n, n), np.int8)
    r, c = np.indices((n, n))
    for _ in range(events):
        r0, c0 = rng.uniform(8, n - 8, 2)
        core = rng.uniform(2.0, 4.0)
        read = int(rng.integers(3, NF - 3))
        d = np.hypot(r - r0, c - c0)
        cube[read:, d <= core] += 2e5
        halo = (d > core) & (d <= 1.8 * core)
        step = rng.uniform(8.0, 16.0)
        cube[read:, halo] += step
        cube[read + 1:, halo] += step
        role[(d <= 3 * core) & (role == 0)] = 3
        role[halo] = 1
        role[d <= core] = 2
    free = np.flatnonzero(role.ravel() == 0)
    rays = rng.choice(free, free.size // 400, replace=False)
    flat = cube.reshape(NF, -1)
    for p in rays:
        flat[int(rng.integers(1, NF)):, p] += rng.uniform(30, 1000)
    role.ravel()[rays] = 4
    sat = cube > PEDESTAL + FULL
    sat = np.maximum.accumulate(sat, axis=0)
    cube[sat] = PEDESTAL + FULL
    flags = np.where(sat, np.uint32(dq.SATURATED), np.uint32(0))
    return cube.astype(np.float32), flags, role


def sigma0():
    t = np.arange(NF) * DT
    w = (t - t.mean()) / ((t - t.mean()) ** 2).sum()
    return RN * np.sqrt(w @ w)


def ours(cube, flags, s, large):
    e = Exposure.from_arrays(cube, s, mask=flags)
    steps = [{"detect_jumps": {"read_noise": RN, "large_events": large}},
             {"fit_ramp": {"read_noise": RN}}]
    t0 = time.perf_counter()
    out = Pipeline({"steps": steps}).run(e)
    t = time.perf_counter() - t0
    return out.data.data, out.data.uncertainty.array, ~dq.image_usable(out.dq), t


def stcal(cube, flags, large):
    """stcal's two-point detection (snowballs expanded or not) and OLS_C fit
    (`stcal_peer.run_stcal`)."""
    r = run_stcal(cube, RN, DT, saturated=(flags & dq.SATURATED) != 0,
                  expand_large_events=large)
    return r["slope"], r["err"], r["unusable"], r["time"]


def score(slope, error, lost, role):
    err = np.asarray(slope, np.float64) / sigma0()  # the dark's rate is 0
    halo = (role == 1) & ~lost
    clean = role == 0
    pull = np.asarray(slope, np.float64)[halo] / np.asarray(error, np.float64)[halo]
    return {"halo_wrong": float(np.mean(np.abs(err[halo]) > 5)),
            "halo_err": float(np.mean(~(np.abs(pull) <= 5))),
            "halo_bias": float(err[halo].mean()),
            "halo_lost": float(np.mean(lost[role == 1])),
            "clean_lost": float(np.mean(lost[clean])),
            "clean_rms": float(np.sqrt(np.mean(err[clean & ~lost] ** 2)))}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--events", type=int, default=40)
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--no-stcal", action="store_true")
    args = p.parse_args(argv)
    logging.getLogger("stcal").setLevel(logging.WARNING)
    rng = np.random.default_rng(args.seed)
    s = schedule(args.size)
    cube, flags, role = simulate(args.size, args.events, rng)
    runs = {"ours": ours(cube, flags, s, False), "ours, large_events": ours(cube, flags, s, True)}
    if not args.no_stcal:
        runs["stcal 1.20"] = stcal(cube, flags, False)
        runs["stcal 1.20, expand_large_events"] = stcal(cube, flags, True)
    print(f"{args.size}x{args.size} pixels, {NF} reads, {args.events} snowballs "
          f"({int((role == 1).sum())} halo pixels), seed {args.seed}; sigma0 = "
          f"{sigma0():.4f} e/s\n")
    print("| run | halo wrong > 5 sigma0 | halo > 5 ERR | halo mean error (sigma0) | "
          "halo lost | clean lost | clean rms (sigma0) | time (s) |")
    print("|---|---|---|---|---|---|---|---|")
    scores = {}
    for name, (slope, error, lost, t) in runs.items():
        sc = scores[name] = score(slope, error, lost, role)
        print(f"| {name} | {sc['halo_wrong']:.2%} | {sc['halo_err']:.2%} | "
              f"{sc['halo_bias']:+.3f} | "
              f"{sc['halo_lost']:.2%} | {sc['clean_lost']:.3%} | {sc['clean_rms']:.3f} | "
              f"{t:.2f} |")
    best = scores["ours, large_events"]
    checks = [("halo > 5 ERR <= 1 %", best["halo_err"] <= 0.01),
              ("halo mean error <= 0.1 sigma0", abs(best["halo_bias"]) <= 0.1),
              ("clean lost <= 0.1 %", best["clean_lost"] <= 0.001)]
    print()
    for text, ok in checks:
        print(f"{'PASS' if ok else 'FAIL'}: {text} (ours, large_events)")
    return 0 if all(ok for _, ok in checks) else 1


if __name__ == "__main__":
    sys.exit(main())
