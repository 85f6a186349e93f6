"""Cost of verifying FITS checksums on read (medium file; one process; prints a table).

    python benchmarks/bench_checksum.py [--size 512] [--nframes 20]

Builds a raw ramp file (``size`` x ``size``, 8 channels, S = 24, r = 32, c = 4) in a
temporary directory and times, best and median of repeats:

* the package's verification of every HDU's DATASUM/CHECKSUM (numpy, 1 MB buffer);
* astropy's ``verify_checksum`` of every HDU of the same file, for comparison;
* a streamed ``spherex-default`` reduction of the file with and without the check.

The last line extrapolates the verification to the 1.28 GB full-size ramp.
"""

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy.io import fits

from spherex_reduce import DetectorGeometry, Exposure, Pipeline, ReadoutSchedule, write
from spherex_reduce.io import fits_structure
from spherex_reduce.io.readers import fits_read


def timed(fn, repeat):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return min(times), statistics.median(times)


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--size", type=int, default=512)
    ap.add_argument("--nframes", type=int, default=20)
    args = ap.parse_args()
    s = ReadoutSchedule(DetectorGeometry(args.size, args.size, 8), skip=24, ref_reads=32,
                        ref_mode="distributed", phantom_reads=4, nframes=args.nframes)
    rng = np.random.default_rng(1)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "raw.fits"
        write(Exposure.from_arrays(
            rng.normal(100, 10, (s.nframes, s.n_reads, args.size)).astype("f4"), s,
            phantom=rng.normal(0, 1, (s.nframes, s.n_reads, 8)).astype("f4")), path)
        size = os.path.getsize(path)

        def ours():
            assert not fits_structure.bad_checksums(path, fits_structure.scan_hdus(path))

        def astropys():
            with fits.open(path, memmap=True) as hdul:
                assert all(h.verify_checksum() == 1 for h in hdul)

        pipeline = Pipeline.from_yaml("spherex-default")
        rows = [("verify, numpy (ours)", timed(ours, 30)),
                ("verify, astropy verify_checksum", timed(astropys, 30)),
                ("reduce spherex-default, streamed, with the check",
                 timed(lambda: pipeline.run(path), 7))]
        real = fits_read.bad_checksums  # the name the reader calls
        fits_read.bad_checksums = lambda path, hdus: []
        try:
            rows.append(("reduce spherex-default, streamed, check skipped",
                         timed(lambda: pipeline.run(path), 7)))
        finally:
            fits_read.bad_checksums = real
    print(f"file {size / 1e6:.1f} MB ({args.size}^2, {args.nframes} frames, float32 ramps)")
    print(f"{'work':52s} {'best':>9s} {'median':>9s}")
    for name, (best, median) in rows:
        print(f"{name:52s} {best * 1e3:7.1f} ms {median * 1e3:7.1f} ms")
    rate = size / rows[0][1][0]
    print(f"ours at best: {rate / 1e9:.1f} GB/s, i.e. {1.28e9 / rate:.2f} s for the 1.28 GB "
          f"full-size ramp (astropy: {1.28e9 / (size / rows[1][1][0]):.2f} s)")


if __name__ == "__main__":
    main()
