"""Simulator benchmark: speed against error, full size (2048², 32 ch, S=24, r=32, c=4).

Run from the repository root::

    python benchmarks/bench_simulate.py            # full run, writes README_simulate.md
    python benchmarks/bench_simulate.py --quick    # small N, for a smoke test
    python benchmarks/bench_simulate.py --small-only   # only the small scenes (no full size);
                                                       # replaces their section of the report

Everything is measured in one process.  Peak RSS per phase comes from a thread
sampling ``/proc/self/status`` every 10 ms (``VmRSS``), so phases do not hide
behind the process-lifetime high-water mark; ``VmHWM`` is printed as well.

Small scenes (64², 16 channels, a 2000-sample row overhead: issue 11 §4) take
the exact route of slope mode; their rows give the first image of a scene
(nothing cached), the next images of the same scene (factors cached), the
tiered route for comparison, and the mean square slope of many images against
the analytic value.

Errors against the analytic, aperiodic slope variance
(`spherex_reduce.expected_slope_variance`) are computed two ways:
*expected* is the exact ensemble variance of the simulator for a pixel
(`NoiseEngine.expected_slope_variance`: spectral weights of every tier pushed
through the interpolation and the least-squares weights, no Monte Carlo
noise); *measured* is the mean square slope of simulated images with its
standard error.
"""

import argparse
import os
import platform
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

from spherex_reduce import expected_slope_variance, simulate
from spherex_reduce.analysis.spectrum import band_power
from spherex_reduce.noise.variance import ls_weights
from spherex_reduce.simulation import (
    NoiseComponent,
    NoiseEngine,
    exact_slopes,
    load_scene,
    simulate_to_fits,
)

HERE = Path(__file__).resolve().parent


class RSS:
    """Peak resident memory (MB) of this process over a ``with`` block."""

    def __enter__(self):
        self.peak = self._now()
        self._stop = threading.Event()
        self._t = threading.Thread(target=self._run, daemon=True)
        self._t.start()
        return self

    @staticmethod
    def _now():
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
        return float("nan")

    def _run(self):
        while not self._stop.wait(0.01):
            self.peak = max(self.peak, self._now())

    def __exit__(self, *exc):
        self._stop.set()
        self._t.join()
        self.peak = max(self.peak, self._now())


def hwm():
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024
    return float("nan")


def floor_time(schedule, threads=1):
    """Seconds to draw the cube's white Gaussian samples (float32, SFC64), frame by frame."""
    shape = (schedule.n_reads, schedule.geometry.ncols)
    n = schedule.nframes
    if threads == 1:
        rng = np.random.Generator(np.random.SFC64(0))
        buf = np.empty(shape, np.float32)
        t = time.perf_counter()
        for _ in range(n):
            rng.standard_normal(dtype=np.float32, out=buf)
        return time.perf_counter() - t
    from concurrent.futures import ThreadPoolExecutor

    rngs = [np.random.Generator(np.random.SFC64(i)) for i in range(threads)]
    bufs = [np.empty((shape[0] // threads + 1, shape[1]), np.float32) for _ in range(threads)]
    with ThreadPoolExecutor(threads) as pool:
        t = time.perf_counter()
        for _ in range(n):
            list(pool.map(lambda i: rngs[i].standard_normal(dtype=np.float32, out=bufs[i]),
                          range(threads)))
        return time.perf_counter() - t


def paper_scene(nframes, **synthesis):
    return {"readout": {"nframes": nframes}, "synthesis": synthesis}


def bench_ramps(nframes, lines, write=True):
    sc = load_scene(paper_scene(nframes))
    s = sc.schedule
    fl1 = floor_time(s)
    fl2 = floor_time(s, threads=2)
    lines.append(f"floor: draw {s.nframes} x {s.n_reads} x {s.geometry.ncols} = "
                 f"{s.nframes * s.n_reads * s.geometry.ncols / 1e6:.0f} M float32 normals: "
                 f"{fl1:.2f} s (1 thread), {fl2:.2f} s (2 threads)")
    with RSS() as mem:
        t = time.perf_counter()
        eng = NoiseEngine(s, sc.components, 1)
        for _ in eng.frames():
            pass
        gen = time.perf_counter() - t
        del eng  # its slow grids must not count against the next phase
    lines.append(f"ramps N={nframes}, generate only: {gen:.2f} s = {gen / fl1:.2f} x floor "
                 f"(1 thread), {gen / fl2:.2f} x floor (2 threads); peak RSS {mem.peak:.0f} MB")
    res = {"gen": gen, "floor1": fl1, "floor2": fl2, "rss_gen": mem.peak}
    if write:
        with tempfile.TemporaryDirectory(dir=os.environ.get("BENCH_TMP")) as d:
            out = Path(d) / "raw.fits"
            with RSS() as mem:
                t = time.perf_counter()
                simulate_to_fits(paper_scene(nframes), out, mode="ramps", seed=1)
                wall = time.perf_counter() - t
            size = out.stat().st_size / 1e9
        lines.append(f"ramps N={nframes}, generate + stream to FITS ({size:.2f} GB, checksums): "
                     f"{wall:.2f} s = {wall / fl1:.2f} x floor (1 thread); "
                     f"peak RSS {mem.peak:.0f} MB")
        res.update(wall=wall, rss_write=mem.peak)
    return res


def bench_slopes(nframes, lines, nreal=3):
    """Slope-image time; slopes against ramps mode (fit of the frames) and the analytic value.

    Realisation ``k`` of both modes uses seed ``k``: their slow tiers (everything
    below ~43 Hz, which dominates the band power) are then the same streams, so
    the comparison isolates what differs between the modes (the fast tier,
    drawn per frame in ramps mode and once, scaled by sqrt(sum w²), in slopes
    mode).  Unpaired, the band power of one image scatters by tens of percent
    from realisation to realisation (a few channel offsets dominate it).
    """
    sc = load_scene(paper_scene(nframes))
    s = sc.schedule
    ana = expected_slope_variance(list(sc.components), s).value
    times, sl_ms, sl_bp, rp_ms, rp_bp = [], [], [], [], []
    w = ls_weights(np.arange(s.nframes) * s.frame_time.value)
    with RSS() as mem:
        for k in range(nreal):
            t = time.perf_counter()
            e = simulate(paper_scene(nframes), seed=k, mode="slopes")
            times.append(time.perf_counter() - t)
            img = np.asarray(e.data.data, float)
            sl_ms.append(np.mean(img**2))
            sl_bp.append(band_power(img).value)
    lines.append(f"slopes N={nframes}: {np.median(times):.2f} s per image (median of "
                 f"{nreal}: {', '.join(f'{x:.2f}' for x in times)} s); peak RSS "
                 f"{mem.peak:.0f} MB")
    for k in range(nreal):
        eng = NoiseEngine(s, sc.components, k)
        acc = np.zeros((s.n_reads, s.geometry.ncols))
        for j, (f, _) in enumerate(eng.frames()):
            acc += w[j] * f
        rp_ms.append(np.mean(acc**2))
        rp_bp.append(band_power(acc).value)
    exp_engine = NoiseEngine(s, [c.replace(acn=False) if c.scope == "channel" else c
                                 for c in sc.components], 0).expected_slope_variance(100, 100)
    sm, rm = np.mean(sl_ms), np.mean(rp_ms)
    lines.append(f"per-pixel slope variance (e/s)^2, mean over the image and {nreal} "
                 f"realisations: analytic {ana:.6g}; simulator exact expectation "
                 f"{exp_engine:.6g} ({exp_engine / ana - 1:+.3%}); slopes mode {sm:.6g} "
                 f"({sm / ana - 1:+.3%}); ramps mode {rm:.6g} ({rm / ana - 1:+.3%}); "
                 f"slopes/ramps {sm / rm - 1:+.3%}")
    white = sum(expected_slope_variance(NoiseComponent("w", alpha=c.alpha), s).value
                for c in sc.components if c.seen_by_pixels)
    colored = 1 - white / ana
    nstreams = 2 * s.geometry.nchannels * nreal
    err = colored * np.sqrt(2 / nstreams)
    lines.append(f"  (standard error of the simulated means ≈ {err:.1%}: "
                 f"the 1/f and 1/f^1.3 terms, {colored:.0%} of the variance, come from "
                 f"{2 * s.geometry.nchannels} even/odd channel streams per image; the two modes "
                 "share seeds, so their ratio is much tighter)")
    ratio = np.array(sl_bp) / np.array(rp_bp)
    lines.append("band power 0.03<k<0.13 rad/pix (raw slope image, readout order), (e/s)^2: "
                 + "; ".join(f"seed {k}: slopes {a:.4g}, ramps {b:.4g}"
                             for k, (a, b) in enumerate(zip(sl_bp, rp_bp, strict=True)))
                 + f"; slopes/ramps {np.mean(ratio) - 1:+.2%} ± "
                 f"{np.std(ratio, ddof=1) / np.sqrt(nreal):.2%}")
    return {"slopes_time": float(np.median(times)), "rss": mem.peak}


def small_scene(nframes):
    """The issue's small scene: 64 x 64, 16 channels of 4 columns, row overhead 2000 samples."""
    return {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 16},
            "readout": {"nframes": nframes, "row_overhead": 2000}}


SMALL_LIMIT = 0.1  # s per slope image, issue 11 target


def bench_small(nframes_list, lines, nimages=200, tiered=True, runs=5):
    """Slope images of the small scene: exact route (cold and warm) against the limit.

    *cold*: median of ``runs`` images each made with the factor cache emptied
    (what a new scene costs); *warm*: median per image over ``nimages`` images
    of one scene with different seeds (a sweep over realisations).  The error
    is the mean square slope of the ``nimages`` images against
    `expected_slope_variance`, with its standard error (image-to-image scatter
    / sqrt(nimages)).  The tiered route (the only route before) is timed once.
    """
    lines.append("")
    lines.append("| scene | route | ours, first image (s) | ours, next images (s) | limit (s) "
                 "| ratio (first / limit) | tiered route (s) | mean square / analytic − 1 |")
    lines.append("|---|---|---|---|---|---|---|---|")
    for n in nframes_list:
        sc = load_scene(small_scene(n))
        ana = expected_slope_variance(list(sc.components), sc.schedule).value
        route = NoiseEngine(sc.schedule, sc.components, 0).slope_route
        cold = []
        for k in range(runs):
            exact_slopes._EXACT_FACTORS.clear()
            t = time.perf_counter()
            simulate(small_scene(n), seed=1000 + k, mode="slopes")
            cold.append(time.perf_counter() - t)
        ms = []
        t = time.perf_counter()
        for k in range(nimages):
            e = simulate(small_scene(n), seed=k, mode="slopes")
            ms.append(np.mean(np.asarray(e.data, float) ** 2) / ana)
        warm = (time.perf_counter() - t) / nimages
        tier = "not run"
        if tiered:
            eng = NoiseEngine(sc.schedule, sc.components, 0, slope_route="tiered")
            t = time.perf_counter()
            eng.slopes()
            tier = f"{time.perf_counter() - t:.2f}"
        cold_med = float(np.median(cold))
        lines.append(f"| 64², 16 ch, row overhead 2000, N = {n} | {route} | {cold_med:.3f} "
                     f"(median of {runs}: {min(cold):.3f}-{max(cold):.3f}) | {warm:.4f} | "
                     f"{SMALL_LIMIT} | {cold_med / SMALL_LIMIT:.2f} | {tier} | "
                     f"{np.mean(ms) - 1:+.2%} ± {np.std(ms, ddof=1) / np.sqrt(nimages):.2%} "
                     f"({nimages} images) |")
    lines.append("")
    lines.append("Times are in process (`simulate(scene, mode='slopes')`, scene terms and "
                 "Exposure included); the exact route's covariance matches the analytic one "
                 "to rounding (tests/simulation/test_slope_routes.py), so the error column is "
                 "Monte Carlo scatter.")


def speed_error_table(nframes_list, lines):
    """Each synthesis option: slope-image time (full size) and bias against the analytic value."""
    comps = {"gamma/f^1.3": NoiseComponent("g", gamma=0.1),
             "beta/f": NoiseComponent("b", beta=8.4e-3)}
    options = [
        ("gaussian, padding 16 (default)", {"padding": 16}),
        ("gaussian, padding 8", {"padding": 8}),
        ("gaussian, padding 4", {"padding": 4}),
        ("gaussian, padding 2", {"padding": 2}),
        ("gaussian, padding 1 (period = exposure)", {"padding": 1}),
        ("random_phase, padding 1 (paper eq. 2-5)", {"method": "random_phase", "padding": 1}),
        ("random_phase, padding 16", {"method": "random_phase", "padding": 16}),
        ("gaussian, padding 16, tier oversampling 8", {"padding": 16, "oversample": 8}),
        ("gaussian, padding 16, tier oversampling 32", {"padding": 16, "oversample": 32}),
        ("gaussian, padding 16, float64", {"padding": 16, "dtype": np.float64}),
    ]
    head = "| option | slopes time (s) | " + " | ".join(
        f"{name} N={n}" for n in nframes_list for name in comps) + " |"
    lines.append("")
    lines.append(head)
    lines.append("|" + "---|" * (2 + len(comps) * len(nframes_list)))
    base = load_scene(paper_scene(74))
    for label, opt in options:
        eng = NoiseEngine(base.schedule, base.components, 5, **opt)
        t = time.perf_counter()
        eng.slopes()
        dt = time.perf_counter() - t
        cells = []
        for n in nframes_list:
            sc = load_scene(paper_scene(n))
            for comp in comps.values():
                ana = expected_slope_variance(comp, sc.schedule).value
                v = NoiseEngine(sc.schedule, [comp], 0, **opt).expected_slope_variance(10, 10)
                cells.append(f"{v / ana - 1:+.2%}")
        lines.append(f"| {label} | {dt:.2f} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("Errors are the simulator's exact ensemble slope variance (no Monte Carlo "
                 "noise) against the analytic aperiodic value, per component; the slopes time is "
                 "one full-size slope image with all Table 2 terms (N = 74).")


def _replace_section(path, section):
    """Put ``section`` (lines, starting with its ``## `` title) into the report at ``path``,
    replacing the section of that title or going before "## Speed against error"."""
    text = path.read_text().splitlines()
    title = section[0]
    if title in text:
        i = text.index(title)
        j = next((m for m in range(i + 1, len(text)) if text[m].startswith("## ")), len(text))
    else:
        i = j = text.index("## Speed against error")
    path.write_text("\n".join([*text[:i], *section, "", *text[j:]]) + "\n")


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--quick", action="store_true", help="N = 8 instead of 74, no N = 386")
    p.add_argument("--no-write", action="store_true", help="do not write README_simulate.md")
    p.add_argument("--small-only", action="store_true",
                   help="only the small scenes (no full-size work)")
    args = p.parse_args(argv)
    lines = [f"machine: {platform.processor() or platform.machine()}, {os.cpu_count()} cores, "
             f"python {sys.version.split()[0]}, numpy {np.__version__}",
             f"date: {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}",
             "load average at start (other jobs share the 2 cores; the floor is measured "
             f"in the same process to normalise): {os.getloadavg()[0]:.2f}", ""]
    n = 8 if args.quick else 74

    def show(start):
        for line in lines[start:]:
            print(line, flush=True)
        return len(lines)

    k = show(0)
    if args.small_only:
        lines.append("## Small scenes (slopes, exact route)")
        lines.append(f"(`python benchmarks/bench_simulate.py --small-only`, {lines[1][6:]}, "
                     f"load {os.getloadavg()[0]:.2f} at start)")
        bench_small([2, 10, 74], lines, nimages=20 if args.quick else 200, tiered=not args.quick)
        show(k)
        if not args.no_write:
            _replace_section(HERE / "README_simulate.md", lines[k:])
        return
    lines.append("## Ramps (full size, all Table 2 terms with ACN)")
    bench_ramps(n, lines)
    if not args.quick:
        bench_ramps(386, lines, write=True)
    k = show(k)
    lines.append("")
    lines.append("## Slopes (full size, all Table 2 terms with ACN)")
    bench_slopes(n, lines, nreal=2 if args.quick else 3)
    k = show(k)
    lines.append("")
    lines.append("## Small scenes (slopes, exact route)")
    bench_small([2, 10, 74], lines, nimages=20 if args.quick else 200, tiered=not args.quick)
    k = show(k)
    lines.append("")
    lines.append("## Speed against error")
    speed_error_table([10, 74] if not args.quick else [10], lines)
    lines.append("")
    lines.append(f"process VmHWM (lifetime peak RSS): {hwm():.0f} MB; load average at end: "
                 f"{os.getloadavg()[0]:.2f}")
    show(k)
    if not args.no_write:
        text = ["# Simulator benchmark", "",
                "Command: `python benchmarks/bench_simulate.py`"
                + (" --quick" if args.quick else ""), "", *lines, ""]
        (HERE / "README_simulate.md").write_text("\n".join(text))


if __name__ == "__main__":
    main()
