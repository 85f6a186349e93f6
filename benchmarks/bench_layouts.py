"""Every input layout of the Measured darks guide at full size, against numpy.

For each layout the script builds a dark in that layout (the stored image as the
lab or mission writes it: uint16 ADU, an offset per read and output in every
pixel, a slope and white noise in the light-sensitive pixels), reduces it with
``spherex-reduce reduce`` in this process (unchop, the ``mean`` reference
correction, ``fit_ramp``), and computes the slopes independently with numpy:
each output's reference rows averaged per read and subtracted, then a least-squares
line through the reads at their times.  It prints our time, numpy's, the ratio,
the largest slope difference in units of the pixels' slope scatter, and whether
the input file's bytes are unchanged.

    python benchmarks/bench_layouts.py            # full size (~2 GB of temporary files)
    python benchmarks/bench_layouts.py --quick    # small arrays, a smoke run

Layouts: JWST SIDECAR in detector orientation (4 outputs as column stripes) and in
NIRSpec's science orientation (outputs as bands of rows, read along the columns),
HST WFC3/IR (quadrants read from the outer corners; the reads as SCI extensions
at uneven SAMPTIMEs, latest first), a Roman-like H4RG-10 corner and one output of
a PRIME-like H4RG (windows of the 4096² array), and one file per read with a mask
file (``--reads-dq``).
"""

import argparse
import contextlib
import io
import tempfile
import time
from pathlib import Path

import numpy as np
from astropy.io import fits

from spherex_reduce.cli import main
from spherex_reduce.reduce.batch import input_digest

RNG = np.random.default_rng(2026)
STEPS = """steps:
  - unchop: {}
  - correct_reference: {strategy: mean}
  - fit_ramp: {}
"""
READOUT = """readout:
  skip: 1
  ref_reads: 0
  ref_mode: none
  phantom_reads: 0
  row_overhead: 0
"""


def _digest(paths):
    return [input_digest(p) for p in paths]


def _ramps(t, nrows, ncols, reference, channel, sigma=3.0):
    """Counts ``(reads, nrows, ncols)`` in the stored orientation: 10000 + an offset per
    read and channel everywhere, + rate t + noise on the light-sensitive pixels."""
    nchan = int(channel.max()) + 1
    offset = RNG.normal(0.0, 40.0, (t.size, nchan))
    rate = RNG.uniform(0.5, 3.0, (nrows, ncols))
    rate[reference] = 0.0
    out = np.empty((t.size, nrows, ncols), np.uint16)
    for k, tk in enumerate(t):
        frame = 10000.0 + offset[k][channel] + rate * tk
        frame += RNG.normal(0.0, sigma, (nrows, ncols)) * ~reference
        out[k] = np.round(frame)
    return out


def _numpy_slopes(counts, t, ref_rows, channel):
    """Independent slopes: per read and channel, the mean of that channel's pixels in its
    reference rows (``ref_rows``: a boolean image) subtracted; then least squares on t."""
    data = counts.astype(np.float64)
    for c in range(int(channel.max()) + 1):
        sel = channel == c
        level = data[:, ref_rows & sel].mean(axis=1)
        data[:, sel] -= level[:, None]
    design = np.vstack([t - t.mean(), np.ones_like(t)]).T
    coef = np.linalg.lstsq(design, data.reshape(t.size, -1), rcond=None)[0]
    return coef[0].reshape(counts.shape[1:])


def _border(nrows, ncols, top, bottom, left, right):
    m = np.zeros((nrows, ncols), bool)
    m[:top] = True
    m[nrows - bottom:] = True
    m[:, :left] = True
    m[:, ncols - right:] = True
    return m


def _write_cube(path, counts):
    sci = fits.ImageHDU(counts, name="SCI")
    sci.header["BUNIT"] = "ADU"
    fits.HDUList([fits.PrimaryHDU(), sci]).writeto(path)


def _cube_of(path):
    return fits.getdata(path, "SCI")


def case_sidecar(where, n, reads, science):
    """SIDECAR: 4 outputs of n/4 columns (detector orientation), border 4 all round; the
    science orientation stores the transpose."""
    t = 10.737 * np.arange(reads)
    ref = _border(n, n, 4, 4, 4, 4)
    channel = np.repeat(np.arange(4), n // 4)[None, :].repeat(n, 0)
    ref_rows = np.zeros((n, n), bool)
    ref_rows[:4] = ref_rows[-4:] = True
    counts = _ramps(t, n, n, ref, channel)
    name = "SIDECAR-science" if science else "SIDECAR"
    if science:  # stored as the transpose: outputs are bands of rows
        counts, ref, ref_rows, channel = (counts.transpose(0, 2, 1).copy(), ref.T,
                                          ref_rows.T, channel.T)
    path = where / f"{name}.fits"
    _write_cube(path, counts)
    yaml = (f"input: {{unit: adu}}\ngeometry:\n  preset: {name}\n  nrows: {n}\n  ncols: {n}\n"
            f"{READOUT}  nframes: {reads}\n  frame_time: 10.737\n{STEPS}")
    label = ("SIDECAR, NIRSpec science orientation (channels: rows)" if science
             else "SIDECAR, detector orientation (channels: columns)")
    return dict(name=f"{label}, {n}x{n}x{reads}", argv=[str(path)], inputs=[path], yaml=yaml,
                ref=ref, numpy=lambda: _numpy_slopes(_cube_of(path), t, ref_rows, channel))


def case_wfc3(where, n, reads):
    """WFC3/IR: quadrants read from the outer corners, border 5; the reads as SCI,1 ...
    SCI,n (latest first) with uneven SAMPTIMEs."""
    t = np.r_[0.0, 2.932, 2.932 + 25.0 * np.arange(1, reads - 1)]
    h = n // 2
    ref = _border(n, n, 5, 5, 5, 5)
    rows, cols = np.indices((n, n))
    channel = (rows >= h) * 2 + (cols >= h)
    ref_rows = (rows < 5) | (rows >= n - 5)  # each quadrant's outer rows: its first reads
    counts = _ramps(t, n, n, ref, channel)
    hdus = [fits.PrimaryHDU()]
    for version in range(1, reads + 1):
        k = reads - version
        sci = fits.ImageHDU(counts[k], name="SCI", ver=version)
        sci.header.update(SAMPTIME=t[k], BUNIT="COUNTS")
        hdus.append(sci)
    path = where / "ib_raw.fits"
    fits.HDUList(hdus).writeto(path)
    del counts

    def numpy():
        with fits.open(path) as hdul:
            sci = [h for h in hdul if h.name == "SCI"]
            order = np.argsort([h.header["SAMPTIME"] for h in sci])
            cube = np.stack([sci[i].data for i in order])
            times = np.array([sci[i].header["SAMPTIME"] for i in order])
        return _numpy_slopes(cube, times, ref_rows, channel)

    yaml = (f"input: {{reads: extensions}}\ngeometry:\n  preset: WFC3-IR\n  nrows: {n}\n"
            f"  ncols: {n}\n  pixel_rate: 1.0e+5\n{READOUT}  frame_time: 2.932\n{STEPS}")
    return dict(name=f"WFC3/IR quadrants, {reads} SCI extensions, {n}x{n}", argv=[str(path)],
                inputs=[path], yaml=yaml, ref=ref, numpy=numpy)


def case_window(where, nrows, ncols, first_column, reads):
    """A window of a 4096² H4RG (32 outputs of 128 columns, alternate scan, border 4)."""
    t = 3.04 * np.arange(reads)
    bottom = 4 if nrows == 4096 else 0
    ref = _border(nrows, ncols, 4, bottom, 4 if first_column == 0 else 0, 0)
    channel = np.zeros((nrows, ncols), int)
    ref_rows = _border(nrows, ncols, 4, bottom, 0, 0)
    path = where / f"window_{first_column}.fits"
    _write_cube(path, _ramps(t, nrows, ncols, ref, channel))
    yaml = (f"input: {{unit: adu}}\ngeometry:\n  nrows: {nrows}\n  ncols: {ncols}\n"
            f"  pixel_rate: 2.0e+5\nwindow:\n  first_row: 0\n  first_column: {first_column}\n"
            "  full_nrows: 4096\n  full_ncols: 4096\n  full_nchannels: 32\n"
            f"  full_scan: alternate\n  full_ref_border: 4\n{READOUT}  nframes: {reads}\n"
            f"  frame_time: 3.04\n{STEPS}")
    label = "H4RG corner" if first_column == 0 else f"H4RG output at column {first_column}"
    return dict(name=f"window: {label}, {nrows}x{ncols}x{reads}", argv=[str(path)],
                inputs=[path], yaml=yaml, ref=ref,
                numpy=lambda: _numpy_slopes(_cube_of(path), t, ref_rows, channel))


def case_reads(where, n, reads):
    """One file per read (H2RG preset: 32 outputs, border 4) with one 2-D mask file."""
    t = 1.51 * np.arange(reads)
    ref = _border(n, n, 4, 4, 4, 4)
    channel = (np.arange(n) // (n // 32))[None, :].repeat(n, 0)
    ref_rows = _border(n, n, 4, 4, 0, 0)
    counts = _ramps(t, n, n, ref, channel)
    mask = np.zeros((n, n), np.int32)
    bad = (RNG.integers(4, n - 4, 50), RNG.integers(4, n - 4, 50))
    mask[bad] = 1
    folder = where / "reads"
    folder.mkdir()
    files = []
    for k in range(reads):
        files.append(folder / f"read_{k + 1}.fits")
        _write_cube(files[-1], counts[k])
    fits.PrimaryHDU(mask).writeto(where / "mask.fits")
    del counts

    def numpy():
        out = _numpy_slopes(np.stack([_cube_of(f) for f in files]), t, ref_rows, channel)
        out[fits.getdata(where / "mask.fits") != 0] = np.nan  # every read masked: no slope
        return out

    yaml = (f"input: {{unit: adu}}\ngeometry:\n  preset: H2RG\n  nrows: {n}\n  ncols: {n}\n"
            f"{READOUT}  nframes: {reads}\n  frame_time: 1.51\n{STEPS}")
    return dict(name=f"H2RG, one file per read + one mask file, {n}x{n}x{reads}",
                argv=["--reads", str(folder / "read_*.fits"), "--reads-dq",
                      str(where / "mask.fits")],
                inputs=[*files, where / "mask.fits"], yaml=yaml, ref=ref, numpy=numpy)


def run(case, where):
    """Reduce with the command, in this process; the numpy reference on the same file."""
    config = where / "config.yaml"
    config.write_text(case["yaml"])
    out = where / "slopes.fits"
    before = _digest(case["inputs"])
    start = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()):
        code = main(["-q", "reduce", *case["argv"], "-c", str(config), "-o", str(out)])
    ours = time.perf_counter() - start
    assert code == 0, (case["name"], code)
    start = time.perf_counter()
    expected = case["numpy"]()
    theirs = time.perf_counter() - start
    unchanged = _digest(case["inputs"]) == before
    got = fits.getdata(out, "SCI").astype(np.float64)
    ref = case["ref"]
    light = ~ref & np.isfinite(expected)
    scatter = np.std(expected[light])
    err = np.max(np.abs(got[light] - expected[light])) / scatter
    nan_same = bool(np.array_equal(np.isnan(got[~ref]), np.isnan(expected[~ref])))
    return ours, theirs, err, scatter, unchanged, nan_same


def main_(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quick", action="store_true", help="small arrays (a smoke run)")
    q = p.parse_args(argv).quick
    builders = [
        lambda w: case_sidecar(w, 256 if q else 2048, 10, science=False),
        lambda w: case_sidecar(w, 256 if q else 2048, 10, science=True),
        lambda w: case_wfc3(w, 128 if q else 1024, 16),
        lambda w: case_window(w, 128, 128, 0, 20),
        lambda w: case_window(w, 512 if q else 4096, 128, 384, 10),
        lambda w: case_reads(w, 256 if q else 2048, 10),
    ]
    print("| layout | ours (s) | numpy (s) | ratio | max abs(ours - numpy) / slope scatter "
          "| input unchanged | masked pixels NaN in both |")
    print("|---|---|---|---|---|---|---|")
    for build in builders:
        with tempfile.TemporaryDirectory() as tmp:
            case = build(Path(tmp))
            ours, theirs, err, scatter, unchanged, nan_same = run(case, Path(tmp))
        print(f"| {case['name']} | {ours:.2f} | {theirs:.2f} | {ours / theirs:.2f}x | "
              f"{err:.1e} (scatter {scatter:.3g} ADU/s) | {'yes' if unchanged else 'NO'} | "
              f"{'yes' if nan_same else 'NO'} |", flush=True)


if __name__ == "__main__":
    main_()
