"""``spherex-reduce characterize`` on full-size raw dark files: time and memory against the limits.

Run: ``python benchmarks/bench_characterize_files.py [--dir DIR] [--darks 2] [--size 2048]
[--nframes 74] [--runs 1] [--no-scatter]``.

Issue 33's speed target is a full-size 2048² × 74 dark characterised in ≤ 30 s and
≤ 2 GB.  This runs the command as a user types it, with its default slope scatter
(``--no-scatter``: without), in a child process:

    spherex-reduce characterize DARK1.fits DARK2.fits -c spherex-default -o MODEL.yaml
        --report REPORT.ecsv

on ``--darks`` raw darks of the paper's case (``bench_characterize.scene``: every
Table 2 component, ACN, S = 24, r = 32 distributed, c = 4), simulated once into ``--dir``
as ramp files (1.28 GB each at full size; kept there and re-used by later runs).  For
each of ``--runs`` runs it prints the wall time and the peak resident memory of the
child (``os.wait4``), per dark, against the limits, and from the report every noise term
against the injected truth (the fitted value, its jackknife error and the pull).  The
child inherits the environment: the figures in ``benchmarks/README.md`` were taken with
``OMP_NUM_THREADS=1``, as the command runs its own threads.
"""

import argparse
import hashlib
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy.table import Table

sys.path.insert(0, str(Path(__file__).parent))
from bench_characterize import scene, truth

from spherex_reduce.io import write
from spherex_reduce.simulation import simulate

#: Issue 33's limits: the time per full-size dark; the memory of the process (the darks
#: are read one at a time, so it does not grow with their number).
LIMIT_SECONDS = 30.0
LIMIT_BYTES = 2e9
TERMS = ("alpha", "beta", "gamma")


def darks(args):
    """The dark files of ``args`` in ``args.dir``, simulated where missing."""
    sc = scene(argparse.Namespace(size=args.size, nframes=args.nframes, phantom_reads=4,
                                  scale=1.0, case="paper"))
    digest = hashlib.sha256(json.dumps(sc, sort_keys=True).encode()).hexdigest()[:12]
    paths = []
    for k in range(args.darks):  # named by the scene: another scene is simulated anew
        path = Path(args.dir) / f"dark_{args.size}x{args.nframes}_{digest}_seed{k}.fits"
        if not path.exists():
            t0 = time.perf_counter()
            write(simulate(sc, seed=k), path)
            print(f"simulated {path} in {time.perf_counter() - t0:.1f} s", flush=True)
        paths.append(path)
    return paths


def run(paths, out, scatter):
    """``(wall seconds, peak RSS bytes, report)`` of one run of the command."""
    model, report = out / "model.yaml", out / "report.ecsv"
    for old in (model, report):
        old.unlink(missing_ok=True)
    cmd = [sys.executable, "-m", "spherex_reduce.cli", "characterize", *map(str, paths),
           "-c", "spherex-default", "-o", str(model), "--report", str(report)]
    if not scatter:
        cmd.append("--no-scatter")
    with open(out / "stderr.txt", "w+b") as err:  # a file: a pipe could fill and block
        t0 = time.perf_counter()
        child = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(child.pid, 0)
        wall = time.perf_counter() - t0
        child.returncode = os.waitstatus_to_exitcode(status)
        if child.returncode != 0:
            err.seek(0)
            sys.exit(f"characterize failed: {err.read().decode().strip()}")
    return wall, usage.ru_maxrss * 1024, Table.read(report, format="ascii.ecsv")


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--dir", default=None, help="where the dark files are written and kept "
                   "(default ~/.cache/spherex_reduce/bench_characterize_files)")
    p.add_argument("--darks", type=int, default=2)
    p.add_argument("--size", type=int, default=2048)
    p.add_argument("--nframes", type=int, default=74)
    p.add_argument("--runs", type=int, default=1)
    p.add_argument("--no-scatter", action="store_true", help="the model alone")
    args = p.parse_args()
    if args.dir is None:
        args.dir = Path.home() / ".cache" / "spherex_reduce" / "bench_characterize_files"
    Path(args.dir).mkdir(parents=True, exist_ok=True)
    paths = darks(args)
    rows, report = [], None
    with tempfile.TemporaryDirectory() as tmp:
        for _ in range(args.runs):
            load = os.getloadavg()[0]
            wall, peak, report = run(paths, Path(tmp), not args.no_scatter)
            rows.append((wall, peak, load))
            print(f"run: {wall:.1f} s, peak RSS {peak / 1e9:.2f} GB (load before {load:.1f})",
                  flush=True)
    n = args.darks
    print(f"\n{platform.node()}: {n} darks of {args.size}² x {args.nframes} (paper's case), "
          f"slope scatter {'off' if args.no_scatter else 'on'}, "
          f"OMP_NUM_THREADS={os.environ.get('OMP_NUM_THREADS', 'unset')}\n")
    print("| run | load before | wall | per dark | limit | ratio | peak RSS | limit | ratio |")
    print("|---|---|---|---|---|---|---|---|---|")
    for i, (wall, peak, load) in enumerate(rows):
        print(f"| {i + 1} | {load:.1f} | {wall:.1f} s | {wall / n:.1f} s | {LIMIT_SECONDS:.0f} s "
              f"| {wall / n / LIMIT_SECONDS:.2f} | {peak / 1e9:.2f} GB | {LIMIT_BYTES / 1e9:.0f} "
              f"GB | {peak / LIMIT_BYTES:.2f} |")
    walls = np.array([r[0] for r in rows])
    print(f"\nmedian wall {np.median(walls):.1f} s ({np.median(walls) / n:.1f} s per dark)")
    want = truth(1.0, True)
    print(f"\nThe terms (errors: the jackknife over {n} darks, Student t with {n - 1} degrees "
          "of freedom)\n\n| term | truth | fitted | fitted - truth | error | pull |")
    print("|---|---|---|---|---|---|")
    for row in report:
        if row["kind"] != "component" or row["name"] not in want:
            continue
        t = want[row["name"]][TERMS.index(row["parameter"])]
        pull = (f"{(row['value'] - t) / row['error']:+.2f}" if row["error"] > 0 else "-")
        print(f"| {row['name']}.{row['parameter']} | {t:.3g} | {row['value']:.3g} | "
              f"{row['value'] - t:+.2g} | {row['error']:.2g} | {pull} |")


if __name__ == "__main__":
    main()
