"""Benchmark of the reduction steps at full size (one process; prints a table).

    python benchmarks/bench_reduce.py [--quick] [--no-stcal] [--no-file] [--out FILE.md]
                                      [--only {fit_ramp,correct_reference,reduce}]
                                      [--repeat N]

* ``fit_ramp`` on a (74, 2048, 2048) float32 cube on a 6e4 pedestal (bands of rows on
  the executor's default threads, and on one thread): time against ``cube.sum()`` on the
  same array (target <= 3x), against stcal's OLS_C ramp fit (target >= 50x faster), and
  the largest error against a float64 least-squares reference, in units of the slope's
  sigma (target <= 1e-3).
* ``correct_reference`` (mean) on a 74-frame full-size cube (target <= 1 s).
* ``spherex-reduce reduce`` of a full-size raw FITS file (N = 74, ~1.3 GB in /tmp,
  deleted afterwards): wall time against reading the file's data once (target <= 2x)
  and peak RSS against the file size (target <= 0.35x), each in a fresh subprocess
  writing a new output file (removed before each run, outside the timing); the
  paper's steps in one executor pass (bands of rows of every frame, default threads
  and ``--threads 1``), and the slopes-first config.
* the plugin guide's streaming strategy (``docs/examples/reference_median.py``)
  against ``mean`` on the same file, in-process, interleaved (target <= 1.10x).

The ``fit_ramp`` rows run ``cube.sum()`` and each fit in turn, ``--repeat`` times (default
9), and print medians (min) and the ratio to ``cube.sum()`` pair by pair: median (range),
which holds when the machine's speed drifts; and the CPU seconds of all threads (medians,
and the median of the ratios pair by pair), which a busy machine changes much less.  The
other timings are the best of a few repeats (the reduce rows: 5 interleaved subprocess
repeats, min and median).  ``--quick`` uses N = 10 frames (for a smoke test of the script).
"""

import argparse
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from spherex_reduce import Exposure, ReadoutSchedule, correct_reference, fit_ramp, unchop, write
from spherex_reduce.reduce.options import default_threads
from spherex_reduce.reduce.steps.fit_ramp.step import FitRampStep

READ_NOISE = 10.0


REPEATS = 5  # interleaved repeats of each subprocess command
PARTS = ("fit_ramp", "correct_reference", "reduce")  # the parts --only can choose


def best(fn, repeat=3):
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def make_cube(nframes, schedule, rng, nrows):
    """Float32 ramps on a 6e4 pedestal: 0.02 e/s dark current plus white read noise."""
    t = schedule.frame_starts.value
    cube = np.empty((nframes, nrows, 2048), np.float32)
    for f in range(nframes):
        cube[f] = rng.standard_normal((nrows, 2048), dtype=np.float32)
        cube[f] *= READ_NOISE
        cube[f] += np.float32(6e4 + 0.02 * t[f])
    return cube


def float64_reference(cube, t):
    tc = t - t.mean()
    w = tc / (tc @ tc)
    ref = np.empty(cube.shape[1:])
    for r0 in range(0, cube.shape[1], 128):
        ref[r0:r0 + 128] = np.einsum("f,fij->ij", w, cube[:, r0:r0 + 128].astype(np.float64))
    return ref, READ_NOISE * np.sqrt(w @ w)


def stcal_fit(cube, frame_time):
    from stcal.ramp_fitting.ramp_fit import ramp_fit_data
    from stcal.ramp_fitting.ramp_fit_class import RampData

    ny, nx = cube.shape[1:]
    rd = RampData()
    rd.set_arrays(cube[None], np.zeros((1, *cube.shape), np.uint8),
                  np.zeros((ny, nx), np.uint32), np.zeros((ny, nx), np.float32))
    rd.set_meta(name="MIRI", frame_time=frame_time, group_time=frame_time, groupgap=0,
                nframes=1, drop_frames1=None)
    rd.set_dqflags({"DO_NOT_USE": 1, "SATURATED": 2, "JUMP_DET": 4, "NO_GAIN_VALUE": 8,
                    "UNRELIABLE_SLOPE": 16, "PERSISTENCE": 32, "CHARGELOSS": 64})
    rd.start_row, rd.num_rows = 0, ny
    img, _, _ = ramp_fit_data(rd, False, np.full((ny, nx), 1e4, np.float32),
                              np.ones((ny, nx), np.float32), "OLS_C", "optimal", "none")
    return img["slope"]


def write_raw_file(path, schedule, rng):
    """A full-size raw exposure (readout order) with phantom reads and channel drifts."""
    g = schedule.geometry
    nf, nr = schedule.nframes, schedule.n_reads
    data = np.empty((nf, nr, g.ncols), np.float32)
    phantom = np.empty((nf, nr, g.nchannels), np.float32)
    walk = np.zeros(g.nchannels)
    for f in range(nf):
        steps = rng.normal(0, 3.0, (nr, g.nchannels))
        drift = walk + np.cumsum(steps, axis=0)
        walk = drift[-1]
        data[f] = rng.standard_normal((nr, g.ncols), dtype=np.float32)
        data[f] *= READ_NOISE
        data[f] += (6e4 + np.repeat(drift, g.channel_width, axis=1)).astype(np.float32)
        phantom[f] = drift + rng.normal(0, 5.0, drift.shape)
    write(Exposure.from_arrays(data, schedule, phantom=phantom), path, overwrite=True)
    return path


def measured(cmd):
    """Wall time and peak RSS (bytes) of a command run in a fresh subprocess."""
    probe = ("import resource, subprocess, sys, time; t0 = time.perf_counter(); "
             "r = subprocess.run(sys.argv[1:]); dt = time.perf_counter() - t0; "
             "print(r.returncode, dt, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)")
    out = subprocess.run([sys.executable, "-c", probe, *cmd], capture_output=True, text=True,
                         check=True)
    code, dt, rss = out.stdout.split()[-3:]
    if int(code):
        raise RuntimeError(f"{cmd} failed: {out.stderr[-2000:]}")
    return float(dt), int(rss) * 1024


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--quick", action="store_true", help="N = 10 frames")
    p.add_argument("--no-stcal", action="store_true")
    p.add_argument("--no-file", action="store_true", help="skip the FITS reduce benchmark")
    p.add_argument("--only", choices=PARTS, help="run one part of the benchmark")
    p.add_argument("--repeat", type=int, default=9,
                   help="fit_ramp rows: runs of each, interleaved with cube.sum() (default 9)")
    p.add_argument("--out", help="also write the table (markdown) here")
    args = p.parse_args(argv)
    nframes = 10 if args.quick else 74
    rng = np.random.default_rng(1)
    rows = []

    def row(work, ours, peer_label, peer, ratio, error="", target=""):
        rows.append((work, ours, peer_label, peer, ratio, error, target))
        print(" | ".join(str(c) for c in rows[-1]), flush=True)

    s = ReadoutSchedule(nframes=nframes)
    parts = [args.only] if args.only else [p for p in PARTS if p != "reduce" or not args.no_file]
    if "fit_ramp" in parts:
        bench_fit(s, nframes, rng, row, args.no_stcal, args.repeat)
    if "correct_reference" in parts:
        bench_reference(s, nframes, rng, row)
    if "reduce" in parts:
        bench_file(s, rng, row)
    header = ("| work | ours | peer / limit | peer time | ratio | error / memory | target |\n"
              "|---|---|---|---|---|---|---|")
    table = header + "\n" + "\n".join("| " + " | ".join(r) + " |" for r in rows)
    print()
    print(table)
    if args.out:
        Path(args.out).write_text(
            "# Reduction benchmark\n\n"
            f"`python benchmarks/bench_reduce.py` on {os.cpu_count()} cores "
            f"(numpy {np.__version__}), {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}."
            "\nfit_ramp rows: medians (min) of runs interleaved with cube.sum(), ratio pair "
            "by pair, median (range); CPU seconds of all threads, medians; other timings: the "
            "best of a few repeats; the reduce rows: 5 interleaved subprocess repeats, min and "
            "median.\n\n"
            + table + "\n")
    return 0


def paired(fns, repeat):
    """Wall and CPU (all threads) seconds of each of ``fns`` (a dict), run in turn ``repeat``
    times (interleaved)."""
    times = {k: ([], []) for k in fns}
    for _ in range(repeat):
        for key, fn in fns.items():
            c0, t0 = time.process_time(), time.perf_counter()
            fn()
            times[key][0].append(time.perf_counter() - t0)
            times[key][1].append(time.process_time() - c0)
    return {k: (np.array(w), np.array(c)) for k, (w, c) in times.items()}


def bench_fit(s, nframes, rng, row, no_stcal, repeat):
    """fit_ramp and cube.sum() in turn, ``repeat`` times: medians, ratios pair by pair."""
    cube = make_cube(nframes, s, rng, 2048)
    e = Exposure.from_arrays(cube, s, order="physical")
    one = FitRampStep(threads=1)
    out, out_one = fit_ramp(e), one.run(e)  # warm-up, and the slopes compared below
    times = paired({"sum": cube.sum, "fit": lambda: fit_ramp(e),
                    "nov": lambda: fit_ramp(e, read_noise=READ_NOISE),
                    "one": lambda: one.run(e)}, repeat)
    t_sum, c_sum = times["sum"]
    ref, sigma = float64_reference(cube, s.frame_starts.value)
    err = np.abs(out.data.data - ref).max() / sigma
    nthreads = default_threads()
    peer = f"{np.median(t_sum):.3f} s (min {t_sum.min():.3f}; CPU {np.median(c_sum):.3f})"

    def timed(key):
        t, c = times[key]
        ratio = t / t_sum
        return (f"{np.median(t):.3f} s (min {t.min():.3f}; CPU {np.median(c):.3f})",
                f"{np.median(ratio):.2f}x ({ratio.min():.2f}-{ratio.max():.2f}x); "
                f"CPU {np.median(c / c_sum):.2f}x")

    row(f"fit_ramp ({nframes}, 2048, 2048) f32, {nthreads} threads", *timed("fit")[:1],
        "cube.sum()", peer, timed("fit")[1], f"{err:.1e} sigma", "<= 3x, <= 1e-3 sigma")
    row("fit_ramp, uncertainty from read_noise", timed("nov")[0], "cube.sum()", peer,
        timed("nov")[1], "", "<= 3x")
    same = "bit for bit" if np.array_equal(out_one.data.data, out.data.data) else "DIFFERENT"
    row("fit_ramp on 1 thread", timed("one")[0], "cube.sum()", peer, timed("one")[1],
        f"{same} as {nthreads} threads", "")
    if not no_stcal:
        t_fit = float(np.median(times["fit"][0]))
        t_st, st = best(lambda: stcal_fit(cube, s.frame_time.value), 1)
        err_st = np.nanmax(np.abs(st - ref)) / sigma
        row("fit_ramp vs stcal OLS_C (same cube)", f"{t_fit:.3f} s", "stcal OLS_C",
            f"{t_st:.1f} s", f"{t_st / t_fit:.0f}x faster", f"stcal {err_st:.1e} sigma",
            ">= 50x")


def bench_reference(s, nframes, rng, row):
    phys = unchop(Exposure.from_arrays(make_cube(nframes, s, rng, s.n_reads), s))
    t_ref, _ = best(lambda: correct_reference(phys, "mean"), 3)
    row(f"correct_reference mean, {nframes} frames", f"{t_ref:.3f} s", "target", "1 s",
        f"{t_ref:.2f}x", "", "<= 1 s")
    t_acn, _ = best(lambda: correct_reference(phys, "acn"), 3)
    row(f"correct_reference acn, {nframes} frames", f"{t_acn:.3f} s", "target", "1 s",
        f"{t_acn:.2f}x", "", "<= 1 s")


def bench_file(s, rng, row):
    with tempfile.TemporaryDirectory(dir="/tmp") as tmp:
        path = Path(tmp) / "raw.fits"
        write_raw_file(path, s, rng)
        size = path.stat().st_size
        read_once = [sys.executable, "-c",
                     "import sys; from astropy.io import fits; "
                     "h = fits.open(sys.argv[1], memmap=False); "
                     "d = h['SCI'].data; print(float(d[-1, -1, -1]))",
                     str(path)]
        exe = [str(Path(sys.executable).parent / "spherex-reduce")]
        cmds = {"read": read_once}
        variants = {"spherex-default": ("spherex-default", []),
                    "spherex-default --threads 1": ("spherex-default", ["--threads", "1"]),
                    "spherex-slopes": ("spherex-slopes", []),
                    # solves its weights in every new process (the CLI's case)
                    "wiener": ("wiener", [])}
        out = Path(tmp) / "out.fits"
        for key, (config, extra) in variants.items():
            cmds[key] = [*exe, "-q", "reduce", str(path), "-c", config, "-o", str(out),
                         *extra]
        runs = {k: [] for k in cmds}
        for _ in range(REPEATS):  # interleaved: the read-once time itself varies a lot
            for key, cmd in cmds.items():
                out.unlink(missing_ok=True)  # a new output each time, as a user writes one
                runs[key].append(measured(cmd))
        t_read = min(t for t, _ in runs["read"])
        m_read = float(np.median([t for t, _ in runs["read"]]))
        rss_read = max(r for _, r in runs["read"])
        for config in variants:
            times = [t for t, _ in runs[config]]
            rss = max(r for _, r in runs[config])
            t_red, m_red = min(times), float(np.median(times))
            row(f"reduce -c {config} ({size / 1e9:.2f} GB file)",
                f"{t_red:.2f} s (median {m_red:.2f})", "read data once",
                f"{t_read:.2f} s (median {m_read:.2f})",
                f"{t_red / t_read:.2f}x (medians {m_red / m_read:.2f}x)",
                f"peak RSS {rss / 1e9:.2f} GB = {rss / size:.2f}x file", "<= 2x, <= 0.35x")
        row("(read data once: peak RSS)", "", "", "", "", f"{rss_read / 1e9:.2f} GB", "")
        bench_plugin_strategy(path, row)


def bench_plugin_strategy(path, row):
    """The plugin guide's streaming strategy against ``mean`` on the same file, in-process."""
    import importlib.util

    from spherex_reduce import Pipeline
    from spherex_reduce.reduce.plugins import Registry, get_plugin_manager

    example = Path(__file__).parents[1] / "docs" / "examples" / "reference_median.py"
    spec = importlib.util.spec_from_file_location("reference_median", example)
    plugin = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(plugin)
    registry = Registry(get_plugin_manager(entry_points=False, plugins=[plugin]))

    def config(strategy):
        return Pipeline({"steps": ["unchop", "subtract_phantom",
                                   {"correct_reference": {"strategy": strategy}},
                                   "fit_ramp"]}, registry=registry)

    pipes = {"mean": config("mean"), "refmedian": config("refmedian")}
    runs = {k: [] for k in pipes}
    for _ in range(REPEATS):  # interleaved, in one process
        for key, pipe in pipes.items():
            t0 = time.perf_counter()
            out = pipe.run(path)
            runs[key].append(time.perf_counter() - t0)
            assert "from a file" in out.tables["PROVENANCE"]["route"][2]  # streamed
    m_mean, m_plugin = (float(np.median(runs[k])) for k in ("mean", "refmedian"))
    row("plugin strategy refmedian (docs example), streamed",
        f"{min(runs['refmedian']):.2f} s (median {m_plugin:.2f})", "strategy mean",
        f"{min(runs['mean']):.2f} s (median {m_mean:.2f})",
        f"{m_plugin / m_mean:.2f}x (medians)", "", "<= 1.10x")


if __name__ == "__main__":
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))
    sys.exit(main())
