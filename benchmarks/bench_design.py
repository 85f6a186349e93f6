"""Benchmark of ``design-readout`` on the paper's case: <= 10 minutes and <= 60 s of CPU.

Run: ``python benchmarks/bench_design.py [DESIGN.yaml] [--write]``; ``--write``
writes ``benchmarks/README_design.md``.  Without a file the design is the
default one (every key at its default: the paper's scene, spherex-default,
the 5-20' band, the paper's 1.51 s frame time, at most 20 paired realisations,
stopping at a gain error of 0.01).  Prints a table: the time of each stage, the
CPU time (user and system, every thread) against the 60 s target, the peak memory,
the forecast band power of the best schedule and of the paper's (S = 24, r = 32
distributed, c = 4, N = 74), the forecast gain, and the paired Monte Carlo's band
powers and gain with their standard errors.
"""

import argparse
import os
import platform
import resource
import time
from pathlib import Path

from spherex_reduce.analysis.design.search import design_readout

LIMIT = 600.0  # s
CPU_LIMIT = 60.0  # s


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("design", nargs="?", default=None, help="DESIGN.yaml (default: {})")
    parser.add_argument("--write", action="store_true", help="write README_design.md")
    args = parser.parse_args(argv)
    t0, r0 = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    res = design_readout(args.design if args.design else {}, progress=True)
    total = time.perf_counter() - t0
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    user, system = r1.ru_utime - r0.ru_utime, r1.ru_stime - r0.ru_stime
    m = res.report.meta
    mc = m.get("monte_carlo") or {}
    unit = m["band_unit"]
    rows = [("stages (s)", ", ".join(f"{k} {v:.0f}" for k, v in m["seconds"].items())),
            ("total time", f"{total:.0f} s (limit {LIMIT:.0f} s): "
                           f"{'PASS' if total <= LIMIT else 'FAIL'}"),
            ("CPU time", f"{user + system:.1f} s (user {user:.1f} s, system {system:.1f} s), "
                         f"limit {CPU_LIMIT:.0f} s: "
                         f"{'PASS' if user + system <= CPU_LIMIT else 'FAIL'}; load average "
                         f"{os.getloadavg()[0]:.1f} at the end"),
            ("peak memory", f"{r1.ru_maxrss / 2**20:.2f} GB (max RSS)"),
            ("schedules forecast", str(m["evaluations"])),
            ("paper's schedule", m["baseline"]["summary"]),
            ("best schedule", f"{m['best']['summary']} ({m['best']['family']} "
                              f"{m['best']['label']})"),
            ("forecast band power, paper", f"{m['band_power_baseline']:.4g} {unit}"),
            ("forecast band power, best", f"{m['band_power_best']:.4g} {unit}"),
            ("forecast gain", f"{100 * m['gain']:.1f} %"),
            ("gain by component (share)", ", ".join(
                f"{c} {100 * p['share_of_gain']:.0f} %" for c, p in
                m["band_power_components"].items() if abs(p["share_of_gain"]) >= 0.005))]
    if mc:
        most = mc.get("most_realizations", mc["realizations"])
        rows += [(f"Monte Carlo, paper ({mc['realizations']} of at most {most} realisations)",
                  f"{mc['band_power_baseline']:.4g} ± {mc['band_power_baseline_err']:.2g}"),
                 ("Monte Carlo, best (same seeds)",
                  f"{mc['band_power_best']:.4g} ± {mc['band_power_best_err']:.2g}"),
                 ("Monte Carlo gain (paired)",
                  f"{100 * mc['gain']:.1f} ± {100 * mc['gain_err']:.1f} % "
                  f"(target >= 20 %: {'met' if mc['gain'] >= 0.2 else 'NOT met'})")]
    width = max(len(r[0]) for r in rows)
    lines = [f"| {'quantity'.ljust(width)} | value |", f"|{'-' * (width + 2)}|-------|"]
    lines += [f"| {a.ljust(width)} | {b} |" for a, b in rows]
    text = "\n".join(lines)
    print(text)
    if args.write:
        Path(__file__).with_name("README_design.md").write_text(
            f"# design-readout on the paper's case\n\n`python benchmarks/bench_design.py"
            f"{' ' + args.design if args.design else ''}` on {platform.node()} "
            f"({os.cpu_count()} cores), {time.strftime('%Y-%m-%d')}:\n\n{text}\n")


if __name__ == "__main__":
    main()
