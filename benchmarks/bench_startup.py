"""Start-up time: ``import spherex_reduce`` and short commands, each in fresh processes.

Every command of ``spherex-reduce`` starts a new interpreter, so the imports it
makes are paid on every run.  This script times, over ``-n`` fresh processes each
(median wall time, interleaved so that a busy machine slows every row alike):

* ``python -c "import spherex_reduce"``;
* ``spherex-reduce --version`` and ``spherex-reduce --help``;
* ``spherex-reduce reduce`` of a small lab dark (40 x 40, two channels, 5 reads of
  uint16 ADU, as ``docs/measured_darks.rst`` makes one), whose reduction itself
  takes a few hundredths of a second;
* ``python -c pass``, the interpreter alone, for reference.

The first three have a limit of 0.3 s.  With ``--baseline VENV`` (a virtual
environment with the package as it was before a change installed, and the same
plugins) the same commands are also run with that environment's ``python`` and
``spherex-reduce``: the column "before".

    python benchmarks/bench_startup.py [-n 15] [--baseline VENV]
"""

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy.io import fits

LIMIT = 0.3  # s, for the import and the commands that do no work

LAB_YAML = """\
input: {unit: adu, gain: 2.0}
geometry: {nrows: 40, ncols: 40, nchannels: 2, pixel_rate: 1.0e+5,
           ref_border: {top: 4, left: 4}}
readout: {skip: 1, ref_reads: 0, ref_mode: none, phantom_reads: 0, nframes: 5,
          frame_time: 2.0}
steps: [unchop, {correct_reference: {strategy: mean}}, fit_ramp]
"""


def make_lab_dark(directory):
    """``lab.fits`` (5 reads of a 40 x 40 dark in uint16 ADU) and ``lab.yaml`` in ``directory``."""
    rng = np.random.default_rng(1)
    t = 2.0 * np.arange(5)
    adu = 1000 + 3.0 * t[:, None, None] + rng.normal(0, 2, (5, 40, 40))
    adu[:, :4, :] -= 3.0 * t[:, None, None]  # reference rows and columns: no signal
    adu[:, 4:, :4] -= 3.0 * t[:, None, None]
    sci = fits.ImageHDU(np.round(adu).astype(np.uint16), name="SCI")
    sci.header["BUNIT"] = "ADU"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(directory / "lab.fits")
    (directory / "lab.yaml").write_text(LAB_YAML)


def commands(work, bindir):
    """``[(what, argv, limit)]`` of the rows, run with the programs in ``bindir``."""
    python, cli = str(bindir / "python"), str(bindir / "spherex-reduce")
    reduce = [cli, "-q", "reduce", str(work / "lab.fits"), "-c", str(work / "lab.yaml"),
              "-o", str(work / "out.fits"), "--overwrite"]
    return [
        ('python -c "import spherex_reduce"', [python, "-c", "import spherex_reduce"], LIMIT),
        ("spherex-reduce --version", [cli, "--version"], LIMIT),
        ("spherex-reduce --help", [cli, "--help"], LIMIT),
        ("spherex-reduce reduce (40 x 40 lab dark)", reduce, None),
        ('python -c "pass" (the interpreter alone)', [python, "-c", "pass"], None),
    ]


def wall(argv, cwd):
    start = time.perf_counter()
    subprocess.run(argv, cwd=cwd, stdout=subprocess.DEVNULL, check=True)
    return time.perf_counter() - start


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("-n", type=int, default=15, help="fresh processes per row (default 15)")
    parser.add_argument("--baseline", type=Path, metavar="VENV",
                        help="a virtual environment with the package before a change")
    args = parser.parse_args(argv)
    bindirs = {"ours": Path(sys.executable).parent}
    if args.baseline is not None:
        bindirs["before"] = args.baseline / "bin"
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        make_lab_dark(work)
        runs = {name: commands(work, bindir) for name, bindir in bindirs.items()}
        times = {(name, i): [] for name in runs for i in range(len(runs["ours"]))}
        for rows in runs.values():  # warm the file cache, byte-compile
            for _, cmd, _ in rows:
                wall(cmd, work)
        for _ in range(args.n):
            for i in range(len(runs["ours"])):
                for name, rows in runs.items():
                    times[name, i].append(wall(rows[i][1], work))
    print(f"median wall time of {args.n} fresh processes each; load average "
          f"{os.getloadavg()[0]:.2f} on {os.cpu_count()} cores\n")
    header = ["what", "ours (s)", "limit (s)", "ours / limit"]
    if args.baseline is not None:
        header += ["before (s)", "before / ours"]
    print("| " + " | ".join(header) + " |")
    print("|" + "---|" * len(header))
    for i, (what, _, limit) in enumerate(runs["ours"]):
        ours = statistics.median(times["ours", i])
        cells = [what, f"{ours:.3f}", "" if limit is None else f"{limit:.1f}",
                 "" if limit is None else f"{ours / limit:.2f}"]
        if args.baseline is not None:
            before = statistics.median(times["before", i])
            cells += [f"{before:.3f}", f"{before / ours:.1f}x"]
        print("| " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
