"""Per-pixel terms of a dark (`fit_pixel_terms`, issue 33): accuracy, time and memory.

Run: ``python benchmarks/bench_pixel_terms.py [--rows 512] [--cols 2048] [--reads 74]
[--seed 1]``.

The issue's target is a full 2048² x 74 dark characterised in <= 30 s and <= 2 GB.  The
dark here is ``--rows`` x ``--cols`` (default 512 x 2048, a quarter of the array: the
fit streams over bands of rows, so its time and the memory of its work arrays scale with
the rows; the full size is extrapolated from two sizes, ``--rows`` and half of it, and
printed).  It is drawn with numpy (our simulator would take minutes at this size; the
tests make the round trip through it at 64 x 64): white read noise ``--sigma`` e,
Poisson dark current, ``--hot`` of the active pixels hot, ``--rtn`` of the active and of
the reference pixels (a 4-pixel border) two-state telegraphs of step ``--amplitude`` e
switching at ``--rate`` Hz (flip probability ``(1 - exp(-2 rate dt)) / 2`` per read, the
simulator's model), read 0 offset by ``--offset`` e, float32 reads 1.5 s apart.

Prints a table: term, truth, fitted, error, pull; then the fit's seconds and its peak
memory (tracemalloc, in a second run: the fit's own allocations, the input cube not
included; the process's maximum resident size as well).
"""

import argparse
import platform
import resource
import time
import tracemalloc

import numpy as np
from astropy import units as u

from spherex_reduce.analysis.pixel_terms import fit_pixel_terms

DT = 1.5


def make_dark(rows, cols, reads, a, seed):
    """A dark cube (float32, e) with known terms, and the reference mask."""
    rng = np.random.default_rng(seed)
    ref = np.zeros((rows, cols), bool)
    ref[:4], ref[-4:], ref[:, :4], ref[:, -4:] = True, True, True, True
    current = np.where(ref, 0.0, a.dark)
    hot = ~ref & (rng.random((rows, cols)) < a.hot)
    current = current + hot * a.hot_current
    tel = rng.random((rows, cols)) < a.rtn
    p = -np.expm1(-2 * a.rate * DT) / 2
    state = rng.random((rows, cols)) < 0.5
    cube = np.empty((reads, rows, cols), np.float32)
    charge = np.zeros((rows, cols))
    for k in range(reads):
        if k:
            charge += rng.poisson(current * DT)
            state ^= rng.random((rows, cols)) < p
        cube[k] = charge + rng.normal(0.0, a.sigma, (rows, cols)) + a.amplitude * (tel & state)
    cube[0] += a.offset
    return cube, ref


def run(rows, a):
    cube, ref = make_dark(rows, a.cols, a.reads, a, a.seed)
    times = np.arange(a.reads) * DT * u.s
    ramps = u.Quantity(cube, u.electron, copy=False)
    t0 = time.perf_counter()
    res = fit_pixel_terms(ramps, times, reference=ref)
    seconds = time.perf_counter() - t0
    tracemalloc.start()  # a second run: tracing slows numpy's allocations
    fit_pixel_terms(ramps, times, reference=ref)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return res, seconds, peak, cube.nbytes


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=512)
    ap.add_argument("--cols", type=int, default=2048)
    ap.add_argument("--reads", type=int, default=74)
    ap.add_argument("--sigma", type=float, default=10.0)
    ap.add_argument("--dark", type=float, default=0.5)
    ap.add_argument("--hot", type=float, default=0.01)
    ap.add_argument("--hot-current", type=float, default=20.0)
    ap.add_argument("--rtn", type=float, default=0.02)
    ap.add_argument("--amplitude", type=float, default=150.0)
    ap.add_argument("--rate", type=float, default=0.03)
    ap.add_argument("--offset", type=float, default=-18.0)
    ap.add_argument("--seed", type=int, default=1)
    a = ap.parse_args()
    print(f"# bench_pixel_terms: {a.rows} x {a.cols} x {a.reads} float32 dark, "
          f"{platform.processor() or platform.machine()}, numpy {np.__version__}")
    res, seconds, peak, nbytes = run(a.rows, a)
    truth = [("read_noise", "active", a.sigma), ("read_noise", "reference", a.sigma),
             ("dark_current", "active", a.dark), ("hot_pixel_fraction", "active", a.hot),
             ("hot_pixel_current", "active", a.hot_current),
             ("first_read_offset", "all", a.offset)]
    for pixels in ("active", "reference"):
        truth += [("telegraph_fraction", pixels, a.rtn),
                  ("telegraph_amplitude", pixels, a.amplitude),
                  ("telegraph_rate", pixels, a.rate)]
    print(f"{'term':<22} {'pixels':<10} {'truth':>10} {'fitted':>11} {'error':>10} "
          f"{'pull':>6}  unit")
    for term, pixels, value in truth:
        r = res.row(term, pixels)
        pull = (r["value"] - value) / r["error"]
        print(f"{term:<22} {pixels:<10} {value:>10.4g} {r['value']:>11.5g} {r['error']:>10.3g} "
              f"{pull:>6.2f}  {r['unit']}")
    _, s_half, p_half, _ = run(a.rows // 2, a)
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    scale = 2048 / a.rows * 2048 / a.cols
    # time and the fit's memory are linear in the rows: a + b * rows from the two sizes
    t_full = s_half + (seconds - s_half) * (2048 - a.rows // 2) / (a.rows - a.rows // 2)
    t_full *= 2048 / a.cols
    m_full = p_half + (peak - p_half) * (2048 - a.rows // 2) / (a.rows - a.rows // 2)
    m_full *= 2048 / a.cols
    cube_full = nbytes * scale
    print(f"\nfit: {seconds:.1f} s, peak {peak / 2**20:.0f} MiB (the input cube "
          f"{nbytes / 2**20:.0f} MiB apart; process max RSS {rss:.0f} MiB); "
          f"{a.rows // 2} rows: {s_half:.1f} s, {p_half / 2**20:.0f} MiB")
    print(f"2048 x 2048 x {a.reads}, extrapolated (linear in rows): {t_full:.0f} s, fit "
          f"{m_full / 2**20:.0f} MiB + the float32 cube {cube_full / 2**20:.0f} MiB = "
          f"{(m_full + cube_full) / 2**30:.2f} GiB")


if __name__ == "__main__":
    main()
