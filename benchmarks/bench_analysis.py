"""Benchmarks of issue 5: ``power_spectrum`` on 2048² ≤ 0.5 s; the Fig. 6 sweep ≤ 5 min.

Run: ``python benchmarks/bench_analysis.py [--sweep] [--write]``; ``--write``
replaces ``benchmarks/README_analysis.md``.  ``--sweep`` also runs the paper's
Fig. 6 at full size (16 values of S × 5 realisations, 2048², N = 74, slopes,
spherex-default, k_y = 0 excluded) on a LocalCluster of 1 and of 2 worker
processes and reports the wall times and the speed-up.  Each case is timed ``REPEAT``
times after one warm-up call (the first call also builds the cached Fourier
grid; its time is reported separately) and the median is compared with the
limit.  The accuracy column checks the normalisation on the same white-noise
image: the mode-weighted mean of P(k) against σ² = 1.
"""

import argparse
import os
import platform
import time
from pathlib import Path

import numpy as np

from spherex_reduce.analysis import band_power, power_spectrum

REPEAT = 5
N = 2048


def timed(fn, repeat=REPEAT):
    t0 = time.perf_counter()
    out = fn()
    first = time.perf_counter() - t0
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return out, first, float(np.median(times))


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help="update README_analysis.md")
    parser.add_argument("--sweep", action="store_true", help="also time the Fig. 6 sweep")
    args = parser.parse_args(argv)
    rng = np.random.default_rng(0)
    img = rng.normal(0, 1, (N, N)).astype(np.float32)
    mask = rng.random((N, N)) < 0.02
    cases = [
        ("power_spectrum 2048² float32, 30 bins", lambda: power_spectrum(img), 0.5),
        ("power_spectrum 2048², 2 % pixels masked", lambda: power_spectrum(img, mask=mask), 0.5),
        ("band_power 2048² (exact, one bin)", lambda: band_power(img), 0.5),
    ]
    rows = []
    for name, fn, limit in cases:
        out, first, med = timed(fn)
        if hasattr(out, "colnames"):
            n = np.asarray(out["nmodes"], float)
            err = abs(np.sum(np.asarray(out["power"]) * n) / n.sum() - 1.0)
        else:
            err = abs(float(out.value) - 1.0)
        rows.append((name, first, med, limit, med / limit, err))
    header = ("| case | first call (s) | median (s) | limit (s) | median / limit | "
              "\\|P/σ² − 1\\| |\n|---|---|---|---|---|---|")
    lines = [header] + [f"| {n} | {f:.3f} | {m:.3f} | {lim:.1f} | {r:.2f} | {e:.1e} |"
                        for n, f, m, lim, r, e in rows]
    table = "\n".join(lines)
    print(table)
    ok = all(r[4] <= 1 for r in rows)
    sweep_text = ""
    if args.sweep:
        sweep_text, sweep_ok = bench_sweep()
        ok = ok and sweep_ok
    print("PASS" if ok else "FAIL: over the limit")
    if args.write:
        readme = Path(__file__).with_name("README_analysis.md")
        readme.write_text(
            "# Analysis benchmark\n\n"
            "`power_spectrum` on a 2048 × 2048 image must take ≤ 0.5 s (issue 5). "
            "Measured with `python benchmarks/bench_analysis.py --write` on "
            f"{platform.machine()}, {platform.python_implementation()} "
            f"{platform.python_version()}, numpy {np.__version__} "
            f"({time.strftime('%Y-%m-%d', time.gmtime())}, 1-minute load average "
            f"{os.getloadavg()[0]:.1f} on 2 cores); median of {REPEAT} calls after a "
            "warm-up (the first call also builds the cached Fourier grid for the shape).\n\n"
            f"{table}\n\n"
            + (sweep_text + "\n\n" if sweep_text else "")
            + "The last column is the normalisation error on the benchmark's own white-noise "
            "image (σ = 1): the mode-weighted mean of P(k) over all bins, or the band power, "
            "against σ²; it is statistical (≈ 1/√modes).\n"
        )
        print(f"wrote {readme}")
    return 0 if ok else 1


def bench_sweep():
    """Fig. 6 at full size on a LocalCluster of 1 and 2 processes; (markdown, ok)."""
    import numpy as np

    from spherex_reduce.analysis.figures.reproduce import FigureSettings
    from spherex_reduce.analysis.sweep import run_sweep

    s = FigureSettings.full()
    sweep = {"scene": {"readout": {"nframes": 74}}, "grid": {"skip": list(s.skips)},
             "realizations": 5, "seed": 6, "pipeline": "spherex-default",
             "measure": {"exclude_horizontal": True}}
    times, tables = {}, {}
    load0 = os.getloadavg()[0]
    for workers in (2, 1):
        t0 = time.perf_counter()
        res = run_sweep(sweep, workers=workers)
        times[workers] = time.perf_counter() - t0
        tables[workers] = res.table
        print(f"Fig. 6 sweep, {len(res.table)} cells, {workers} worker(s): "
              f"{times[workers]:.1f} s ({len(res.failed)} failed)")
    same = np.array_equal(tables[1]["band_power"], tables[2]["band_power"])
    load1 = os.getloadavg()[0]
    per_cell = float(np.median(tables[2]["seconds"]))
    text = (
        "## Fig. 6 sweep at full size\n\n"
        f"{len(s.skips)} values of S × 5 realisations = {len(tables[2])} cells, each a "
        "2048² N = 74 slope image simulated, reduced with `spherex-default` and measured "
        "(P(k) and the exact band power), on an embedded `LocalCluster` (processes, one "
        "thread each).\n\n"
        "| workers | wall time (s) | limit (s) | time / limit |\n|---|---|---|---|\n"
        f"| 1 | {times[1]:.1f} | 300 | {times[1] / 300:.2f} |\n"
        f"| 2 | {times[2]:.1f} | 300 | {times[2] / 300:.2f} |\n\n"
        f"Speed-up of 2 workers over 1: {times[1] / times[2]:.2f}× (2 cores). Median time "
        f"per cell {per_cell:.2f} s. Results identical for 1 and 2 workers: {same}. "
        f"1-minute load average {load0:.1f} before and {load1:.1f} after the runs (2 cores): "
        "other jobs on the machine slow these times down and make them vary by tens of per "
        "cent between runs. Each cell already runs on both cores (the simulator's 2-thread "
        "pool and multi-threaded FFTs), so on this 2-core machine a second worker process "
        "adds little throughput; the cluster pays off with more cores or machines "
        "(`--scheduler ADDRESS`)."
    )
    return text, times[2] <= 300 and same


if __name__ == "__main__":
    raise SystemExit(main())
