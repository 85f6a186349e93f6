"""What a batch adds to the reductions it runs (one process; prints a table).

    python benchmarks/bench_batch.py [--files 3] [--size 2048] [--nframes 74] [--repeat 3]

Simulates one raw ramp file (default: the paper's full-size case, 1.28 GB) and copies
it ``files`` times into a temporary directory, then times, in turn and ``repeat``
times each:

* the reductions alone: ``spherex-default`` of every file, each written with
  `spherex_reduce.write` (what a loop over ``spherex-reduce reduce`` does);
* the same files as one serial batch (`spherex_reduce.reduce.batch.run_batch`
  with ``scheduler="serial"``), which also takes every input's SHA-256 (beside
  its reduction), stamps the outputs, and writes the summary after each file;
* a resumed batch: the same command again, when every output is finished (it
  reads each output and hashes each input, and reduces nothing).

The batch's outputs are checked to hold the same slopes as the loop's.
"""

import argparse
import shutil
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy.io import fits

from spherex_reduce import DetectorGeometry, ReadoutSchedule, write
from spherex_reduce.reduce.batch import run_batch
from spherex_reduce.reduce.integrations import reduce_input
from spherex_reduce.reduce.pipeline import as_pipeline
from spherex_reduce.simulation import simulate_to_fits


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--files", type=int, default=3)
    ap.add_argument("--size", type=int, default=2048)
    ap.add_argument("--nframes", type=int, default=74)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    channels = max(1, args.size // 64)
    schedule = ReadoutSchedule(DetectorGeometry(args.size, args.size, channels), skip=24,
                               ref_reads=32, ref_mode="distributed", phantom_reads=4,
                               nframes=args.nframes)
    pipeline = as_pipeline("spherex-default")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        first = tmp / "in" / "raw0.fits"
        first.parent.mkdir()
        simulate_to_fits({"geometry": {"nrows": args.size, "ncols": args.size,
                                       "nchannels": channels},
                          "readout": {"skip": 24, "ref_reads": 32, "phantom_reads": 4,
                                      "nframes": args.nframes}, "seed": 1}, first,
                         mode="ramps")
        inputs = [first] + [tmp / "in" / f"raw{k}.fits" for k in range(1, args.files)]
        for path in inputs[1:]:
            shutil.copyfile(first, path)
        size = first.stat().st_size

        def loop():
            out = tmp / "loop"
            shutil.rmtree(out, ignore_errors=True)
            out.mkdir()
            for path in inputs:
                result, images = reduce_input(str(path), pipeline)
                write(result, out / f"{path.stem}_reduced.fits", images=images)

        def batch():
            shutil.rmtree(tmp / "batch", ignore_errors=True)
            run_batch(pipeline, inputs, tmp / "batch", scheduler="serial")

        def resumed():
            run_batch(pipeline, inputs, tmp / "batch", scheduler="serial")

        times = {"loop": [], "batch": [], "resumed": []}
        for _ in range(args.repeat):
            for name, fn in (("loop", loop), ("batch", batch), ("resumed", resumed)):
                t0 = time.perf_counter()
                fn()
                times[name].append(time.perf_counter() - t0)
        worst = 0.0
        for path in inputs:
            name = f"{path.stem}_reduced.fits"
            a = fits.getdata(tmp / "loop" / name, "SCI")
            b = fits.getdata(tmp / "batch" / name, "SCI")
            worst = max(worst, float(np.nanmax(np.abs(a - b))))
    loop_median = statistics.median(times["loop"])
    print(f"{args.files} files of {size / 1e6:.1f} MB ({args.size}^2, {schedule.nframes} "
          f"frames), spherex-default, {args.repeat} runs each in turn (medians)")
    print(f"{'work':44s} {'ours':>9s} {'limit':>9s} {'ratio':>7s} {'max |diff|':>11s}")
    print(f"{'loop of reductions (the limit)':44s} {loop_median:8.2f}s {loop_median:8.2f}s "
          f"{1.0:6.2f}x {'':>11s}")
    for name, label in (("batch", "serial batch, every output made"),
                        ("resumed", "resumed batch, every output finished")):
        ours = statistics.median(times[name])
        diff = f"{worst:.1e}" if name == "batch" else ""
        print(f"{label:44s} {ours:8.2f}s {loop_median:8.2f}s {ours / loop_median:6.2f}x "
              f"{diff:>11s}")


if __name__ == "__main__":
    main()
