"""``characterize`` on a peer's simulator: NGHXRG 2.6's cubes, each term against its truth.

Run: ``python benchmarks/bench_characterize_nghxrg.py [--nghxrg DIR] [--size 2048]
[--nframes 10] [--darks 4] [--cases white,c_pink,u_pink,acn,all] [--out DIR]``.

NGHXRG (Rauscher et al. 2015, PASP 127, 1144; ``github.com/BJRauscher/nghxrg``, the JWST
noise generator) is not a dependency and is never committed here: ``--nghxrg DIR`` is a
copy of its repository (``nghxrg.py`` and, if present, ``nirspec_pca0.fits``), else the
script clones the pinned commit into ``~/.cache/spherex_reduce/nghxrg``.  Its module
imports ``scipy.ndimage.interpolation.zoom``, which newer scipy may lack: the script
provides it at run time (``scipy.ndimage.zoom``) without touching their file.  Where the
PCA-zero template (``nirspec_pca0.fits``, the picture-frame pattern) is absent, a smooth
stand-in is written to the output directory and said so.

Each case draws ``--darks`` cubes (``--size``² × ``--nframes``, NGHXRG's default SIDECAR
clocking: 4 outputs, 10 µs per pixel, 12 samples of row overhead, one row of frame
overhead, a 4-pixel reference border, outputs read ``-->, <--, -->, <--``) and writes each
as NGHXRG does (a uint16 primary HDU with its ``RD_NOISE`` ... keywords).  They are read
with `CONFIG` (our geometry and readout for that layout) and characterised together.

**Truth.** NGHXRG's white read noise ``rd_noise`` (σ per pixel per read, the reference
pixels ``0.8 σ``) is a one-sided PSD ``2 σ² / f_s`` at the pixel rate ``f_s``; its uint16
truncation adds ``1/12`` ADU² per read.  Each pink stream (``pink_noise``) is unit white
noise filtered by ``f^-1/2`` on a grid of ``L`` samples, one-sided PSD ``2/f`` in ADU²/Hz
whatever the sample rate, then rescaled so that its first ``N`` samples have the standard
deviation of the first half of the seed noise: its level is ``β = 2 A² s²`` for amplitude
``A`` (``c_pink``, ``u_pink``, ``acn``) and the realised rescale ``s`` of that draw, which
the script records (`Recorder`): NGHXRG's rescale varies by ~10 % from draw to draw,
so the truth is that of the cubes drawn.  ``c_pink`` is one stream for all outputs (the
common 1/f), ``u_pink`` one per output, ``acn`` one per output and column parity (each
at half the pixel rate: its level per parity stream is still ``2 A² s²``).  PCA-zero adds
``pca0_amp · P(y, x) · g(row)`` with ``g`` one pink draw per row: a channel's mean sees
``pca0_amp² ⟨m_c m_c'⟩`` times ``g``'s level, ``m_c(y)`` the mean of the template over
the channel's light-sensitive columns.  NGHXRG's other terms (bias pattern, kTC) are
constant per pixel and removed with each pixel's straight line; ``pedestal`` is not
used by version 2.6.

Printed per case: each term's truth, the fitted value ± its jackknife error, the ratio,
the target (white within 5 %, the common and per-output 1/f band power in 1-100 Hz within
15 %, ACN found when present and ruled out when absent) and whether it is met; then
each fitted spectrum's χ²/dof, with a warning when the fit is visibly bad.
"""

import argparse
import importlib.util
import os
import subprocess
import sys
import time
import types
from pathlib import Path

import numpy as np
from astropy.io import fits

from spherex_reduce.analysis.characterize import characterize
from spherex_reduce.analysis.characterize.model import BAD_FIT_PROBABILITY, goodness
from spherex_reduce.analysis.characterize.result import seen_white
from spherex_reduce.analysis.characterize.spectra import band_power
from spherex_reduce.reduce.pipeline import Pipeline

#: The commit of github.com/BJRauscher/nghxrg the benchmark was written against (v2.6).
NGHXRG_URL = "https://github.com/BJRauscher/nghxrg"
NGHXRG_COMMIT = "abc3f16"
CACHE = Path.home() / ".cache" / "spherex_reduce" / "nghxrg"

#: NGHXRG's default noise (JWST NIRSpec), ADU; each case turns some terms off.
DEFAULTS = {"rd_noise": 5.2, "c_pink": 3.0, "u_pink": 1.0, "acn": 0.5, "pca0_amp": 0.2}
CASES = {
    "white": {"c_pink": 0, "u_pink": 0, "acn": 0, "pca0_amp": 0},
    "c_pink": {"u_pink": 0, "acn": 0, "pca0_amp": 0},
    "u_pink": {"acn": 0, "pca0_amp": 0},
    "acn": {"pca0_amp": 0},
    "all": {},
}
NOUT, NROH, NFOH, DT, REF_RATIO = 4, 12, 1, 1e-5, 0.8
BAND = (1.0, 100.0)
#: Targets: relative error of the white levels and of the 1/f band powers.
WHITE_TOL, PINK_TOL = 0.05, 0.15


def config(size, nframes):
    """Our pipeline config for NGHXRG's cubes: its SIDECAR layout and clocking."""
    xsize = size // NOUT
    return {"input": {"unit": "adu"},
            "geometry": {"nrows": size, "ncols": size, "nchannels": NOUT, "ref_border": 4,
                         "scan": "alternate", "pixel_rate": 1.0 / DT},
            "readout": {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
                        "row_overhead": NROH, "frame_overhead": xsize + NROH,
                        "nframes": nframes},
            "steps": ["unchop"]}


# -- NGHXRG itself ----------------------------------------------------------------------
def nghxrg_dir(path):
    """A directory holding NGHXRG's ``nghxrg.py``: ``path``, or a clone in `CACHE`."""
    if path is not None:
        d = Path(path)
        if not (d / "nghxrg.py").is_file():
            sys.exit(f"--nghxrg {d}: no nghxrg.py there")
        return d
    d = CACHE / NGHXRG_COMMIT
    if not (d / "nghxrg.py").is_file():
        print(f"cloning {NGHXRG_URL} at {NGHXRG_COMMIT} into {d}", flush=True)
        d.parent.mkdir(parents=True, exist_ok=True)
        subprocess.run(["git", "clone", "-q", NGHXRG_URL, str(d)], check=True)
        subprocess.run(["git", "-C", str(d), "checkout", "-q", NGHXRG_COMMIT], check=True)
    return d


def load_nghxrg(d):
    """Import NGHXRG's module from ``d``, giving it what newer libraries dropped."""
    import scipy.ndimage

    try:
        import scipy.ndimage.interpolation
    except ImportError:
        shim = types.ModuleType("scipy.ndimage.interpolation")
        shim.zoom = scipy.ndimage.zoom
        sys.modules["scipy.ndimage.interpolation"] = shim
    spec = importlib.util.spec_from_file_location("nghxrg_peer", d / "nghxrg.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def standin_pca0(path, n=2048):
    """A smooth picture-frame stand-in for NGHXRG's PCA-zero template (its shape only
    matters through each output's row mean, which the truth computes from it)."""
    y, x = np.mgrid[0:n, 0:n] / (n - 1.0)
    frame = np.exp(-np.minimum.reduce([x, y, 1 - x, 1 - y]) / 0.05)
    img = (frame + 0.5 * np.cos(2 * np.pi * 1.5 * x) * np.sin(np.pi * y)).astype(np.float32)
    path = Path(path)
    if path.is_file() and np.array_equal(fits.getdata(path), img):
        return path  # another run may be reading it
    tmp = path.with_name(path.name + f".{os.getpid()}.tmp")
    fits.PrimaryHDU(img).writeto(tmp, overwrite=True)
    os.replace(tmp, path)  # whole, never half-written under a running NGHXRG
    return path


def recorder(module):
    """NGHXRG's generator, recording the rescale of every pink draw (``scales[mode]``:
    the realised ``s²``, so that each draw's level is ``2 A² s²``)."""

    class Recorder(module.HXRGNoise):
        def white_noise(self, nstep=None):
            x = super().white_noise(nstep)
            self._seed_noise = x
            return x

        def pink_noise(self, mode):
            out = super().pink_noise(mode)
            x = self._seed_noise
            h = self.p_filter2 if mode == "pink" else self.p_filter1
            y = np.fft.irfft(np.fft.rfft(x) * h)[:out.size]
            self.scales.setdefault(mode, []).append(np.std(x[:x.size // 2]) ** 2 / np.var(y))
            return out

    return Recorder


def draw(module, pca0, size, nframes, params, seed, path, record=True):
    """One cube written as NGHXRG writes it; returns the draw's rescales (``record``: else
    ``{}``, the same cube without the second pass over each pink draw) and template."""
    kind = recorder(module) if record else module.HXRGNoise
    ng = kind(naxis1=size, naxis2=size, naxis3=nframes, n_out=NOUT, dt=DT, nroh=NROH,
              nfoh=NFOH, pca0_file=str(pca0), reference_pixel_border_width=4, det_size=size)
    ng.scales = {}
    np.random.seed(seed)  # noqa: NPY002 (NGHXRG draws from numpy's global generator)
    hdu = ng.mknoise(None, **params)
    hdu.header["SRSEED"] = (seed, "numpy seed of this draw (spherex_reduce benchmark)")
    hdu.header["SRPCA0"] = (Path(pca0).name, "PCA-zero template of this draw")
    hdu.writeto(path, overwrite=True)
    return ng.scales, ng.pca0


#: NGHXRG's header keyword for each noise amplitude it writes.
KEYWORDS = {"rd_noise": "RD_NOISE", "c_pink": "C_PINK", "u_pink": "U_PINK", "acn": "ACN",
            "pca0_amp": "PCA0"}


def cube(module, pca0, size, nframes, params, seed, path):
    """``path`` holding the draw of `draw`: kept from an earlier run when its header says
    the same size, frames, amplitudes, seed and template, else drawn (and written)."""
    path = Path(path)
    if path.is_file():
        h = fits.getheader(path)
        same = ((h.get("NAXIS1"), h.get("NAXIS2"), h.get("NAXIS3")) == (size, size, nframes)
                and h.get("SRSEED") == seed and h.get("SRPCA0") == Path(pca0).name
                and all(np.isclose(h.get(k, np.nan), params[p]) for p, k in KEYWORDS.items()))
        if same:
            return path
    draw(module, pca0, size, nframes, params, seed, path, record=False)
    return path


def peer(path, out):
    """``(directory, module, pca0)``: NGHXRG (`nghxrg_dir`, `load_nghxrg`) and its PCA-zero
    template, or the stand-in (`standin_pca0`) written to ``out`` (said so)."""
    d = nghxrg_dir(path)
    module = load_nghxrg(d)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    pca0 = d / "nirspec_pca0.fits"
    if not pca0.is_file():
        pca0 = standin_pca0(out / "standin_pca0.fits")
        print(f"NGHXRG's nirspec_pca0.fits is absent from {d}: a smooth picture-frame "
              f"stand-in ({pca0}) is used", flush=True)
    return d, module, pca0


# -- the truth --------------------------------------------------------------------------
def truth(params, draws, size):
    """Each term's truth (ADU²/Hz; β in ADU²) for the darks of one case.

    ``draws``: per cube the rescales (``pink`` draws in NGHXRG's order: c_pink, the
    outputs' u_pink, then pca0; ``acn`` two per output) and the PCA-zero template."""
    fs = 1.0 / DT
    rd = params["rd_noise"]
    t = {"white": 2 * (rd**2 + 1 / 12) / fs,
         "white_ref": 2 * ((REF_RATIO * rd) ** 2 + 1 / 12) / fs}
    common, channel, acn, aliased = [], [], [], [0.0]
    xsize = size // NOUT
    for scales, pca0 in draws:
        pink = list(scales.get("pink", []))
        c = 2 * params["c_pink"] ** 2 * pink.pop(0) if params["c_pink"] > 0 else 0.0
        u = (2 * params["u_pink"] ** 2 * np.mean([pink.pop(0) for _ in range(NOUT)])
             if params["u_pink"] > 0 else 0.0)
        p_auto = p_cross = 0.0
        if params["pca0_amp"] > 0:
            g = 2 * params["pca0_amp"] ** 2 * pink.pop(0)
            cols = np.arange(size)
            light = (cols >= 4) & (cols < size - 4)
            m = np.array([pca0[:, (cols // xsize == o) & light].mean(axis=1)
                          for o in range(NOUT)])  # (outputs, rows)
            cov = m @ m.T / m.shape[1]
            p_auto = g * np.mean(np.diag(cov))
            p_cross = g * (cov.sum() - np.trace(cov)) / (NOUT * (NOUT - 1))
            aliased.append(p_auto * pca0_white(size))
        a = (2 * params["acn"] ** 2 * np.mean(scales["acn"]) if params["acn"] > 0 else 0.0)
        common.append(c + p_cross)
        channel.append(u + p_auto - p_cross)
        acn.append(a)
    t.update(common=float(np.mean(common)), channel=float(np.mean(channel)),
             acn=float(np.mean(acn)))
    t["white"] += float(np.mean(aliased[1:])) if len(aliased) > 1 else 0.0
    return t


def pca0_white(size):
    """The white level (per sample, per unit 1/f level of a channel's mean) that PCA-zero's
    one value per row adds: a row's value is a point sample of its pink stream, so the
    stream's power from every multiple ``m f_r`` of the row rate folds onto the channel's
    row-mean stream, which the model takes for white noise averaged over the ``n``
    light-sensitive columns of a row read of ``d`` samples (``α d / n``): ``(n / d) Σ_m≠0
    1/|f + m f_r|``, taken at ``f_r / 4`` (mid-band)."""
    d = size // NOUT + NROH
    n = size // NOUT - 4
    f_r = 1.0 / (DT * d)
    m = np.arange(1, d // 2 + 1)
    f = f_r / 4
    return float(n / d * np.sum(1 / (m * f_r - f) + 1 / (m * f_r + f)))


# -- the comparison ---------------------------------------------------------------------
def band(est, exponent, lo_hi=BAND):
    """An estimate's β, γ band power over ``lo_hi`` and its jackknife error."""
    value = band_power(est.values[1], est.values[2], exponent, lo_hi)
    jack = np.array([band_power(b, g, exponent, lo_hi) for _, b, g in est.leave_one_out])
    k = jack.size
    return value, float(np.sqrt((k - 1) / k * np.sum((jack - jack.mean()) ** 2)))


def chi2_lines(model):
    """``(name, chi2, dof, p)`` of each fitted spectrum of the pooled darks."""
    return [(n, *v) for n, v in goodness(model.bins, NOUT).items()]


def rows(model, want):
    """Table rows ``(term, truth, fitted, error, ratio, target, met)``."""
    e = model.exponent
    ln = np.log(BAND[1] / BAND[0])
    out = []
    comps = model.components
    w, we = comps["channel"].values[0], comps["channel"].errors[0]
    out.append(("white, light-sensitive (channel.alpha)", want["white"], w, we,
                f"within {WHITE_TOL:.0%}", abs(w / want["white"] - 1) <= WHITE_TOL))
    ref = model.spectra.get("reference")
    if ref is not None:
        r, re_ = ref.values[0], ref.errors[0]
        out.append(("white, reference pixels", want["white_ref"], r, re_,
                    f"within {WHITE_TOL:.0%}", abs(r / want["white_ref"] - 1) <= WHITE_TOL))
    # what the scene holds (simulate, forecast and wiener take it): the components' white
    # level on every pixel, the light-sensitive pixels' own read noise on top
    scene = model.scene()
    fs = model.schedule.geometry.pixel_rate
    held = seen_white(scene["noise"]["components"])
    active = (scene.get("scene") or {}).get("active_read_noise", 0.0)
    for term, t, v in (("scene: reference pixels' white (components)", want["white_ref"], held),
                       ("scene: light-sensitive white (+ active_read_noise)", want["white"],
                        held + 2 * active**2 / fs)):
        out.append((term, t, v, None, f"within {WHITE_TOL:.0%}",
                    abs(v / t - 1) <= WHITE_TOL))
    for key, name in (("common", "common"), ("channel", "per-output")):
        v, err = band(comps[key], e)
        tb = want[key] * ln
        if want[key] > 0:
            met = abs(v / tb - 1) <= PINK_TOL
            target = f"within {PINK_TOL:.0%}"
        else:
            met = abs(v) <= 3 * err
            target = "0 within 3 errors"
        out.append((f"{name} 1/f, band power {BAND[0]:g}-{BAND[1]:g} Hz ({key})", tb, v, err,
                    target, met))
    if "acn" in comps:
        v, err = band(comps["acn"], e)
        out.append((f"ACN 1/f per parity stream, {BAND[0]:g}-{BAND[1]:g} Hz (acn)",
                    want["acn"] * ln, v, err, f"within {PINK_TOL:.0%}",
                    want["acn"] > 0 and abs(v / (want["acn"] * ln) - 1) <= PINK_TOL))
    if model.acn is not None:
        found = model.acn["found"]
        present = want["acn"] > 0
        out.append((f"ACN test (z = {model.acn['z']:.1f})", "present" if present else "absent",
                    "found" if found else "ruled out", None,
                    "found iff present", found == present))
    return out


def fmt(x):
    return x if isinstance(x, str) else f"{x:.4g}"


def report(case, params, model, want, seconds):
    lines = [f"\n### {case}: " + ", ".join(f"{k} {v:g}" for k, v in params.items())
             + f" ({len(model.darks)} darks; characterize {seconds:.1f} s)\n",
             "| term | truth | fitted ± error | ratio | target | met |",
             "|---|---|---|---|---|---|"]
    for term, t, v, err, target, met in rows(model, want):
        fitted = fmt(v) if err is None else f"{fmt(v)} ± {err:.2g}"
        ratio = (f"{v / t:.3f}" if not isinstance(t, str) and t != 0 else "-")
        lines.append(f"| {term} | {fmt(t)} | {fitted} | {ratio} | {target} | "
                     f"{'yes' if met else '**no**'} |")
    fits_ = chi2_lines(model)
    lines.append("\nχ²/dof of the pooled fits: " + ", ".join(
        f"{n} {c:.0f}/{d}" for n, c, d, _ in fits_))
    for n, c, d, p in fits_:
        if p < BAD_FIT_PROBABILITY:
            lines.append(f"WARNING: the {n} fit is visibly bad: χ²/dof = {c:.0f}/{d} "
                         f"(probability {p:.1e})")
    skip = ("unit:", "channel_both, channel_phantom", "uncertainties: from the scatter")
    lines.extend(f"mark: {m}" for m in model.marks if not m.startswith(skip))
    return lines


def spectra(model, case, params, lines):
    """The binned spectra ``model``'s plot draws (`Characterization.bins`), one row per bin
    (``name``: the spectrum): what the docs draw a case's figure from without NGHXRG."""
    from astropy import units as u
    from astropy.table import Table, vstack

    parts = []
    for name, b in model.bins.items():
        t = Table({"name": [name] * len(b)})
        for col in ("frequency", "psd", "psd_err", "model"):
            c = b[col]
            t[col] = np.asarray(getattr(c, "value", c), dtype=float)
            t[col].unit = c.unit if getattr(c, "unit", None) is not None else (
                model.unit**2 / u.Hz)
        parts.append(t)
    t = vstack(parts)
    t.meta.update({"case": case, "noise": {k: float(v) for k, v in params.items()},
                   "darks": [Path(d).name for d in model.darks],
                   "segments": int(model.ngroups), "exponent": float(model.exponent),
                   "unit": model.unit.to_string(),
                   "printed": [ln.replace("±", "+/-").replace("χ²", "chi2")
                               for ln in lines if ln.startswith(("| ", "χ²"))
                               and not ln.startswith("| term")]})
    return t


def cube_arguments(p):
    """The options of every benchmark on NGHXRG's cubes, added to parser ``p``: where
    NGHXRG is, the cubes' size and frames, darks per case and the cases."""
    p.add_argument("--nghxrg", help="a copy of NGHXRG's repository (default: clone it)")
    p.add_argument("--size", type=int, default=2048)
    p.add_argument("--nframes", type=int, default=10)
    p.add_argument("--darks", type=int, default=4)
    p.add_argument("--cases", default=",".join(CASES))


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    cube_arguments(p)
    p.add_argument("--out", default="/tmp/nghxrg_cubes", help="where the cubes are written")
    p.add_argument("--exponent", type=float, default=1.3)
    p.add_argument("--plot", metavar="DIR", help="write each case's characterisation plot "
                   "(spectra and fits) as DIR/CASE.png, its binned spectra as "
                   "DIR/CASE-spectra.ecsv and the model's report as DIR/CASE-report.ecsv")
    args = p.parse_args()
    out = Path(args.out)
    d, module, pca0 = peer(args.nghxrg, out)
    cfg = config(args.size, args.nframes)
    lines = [f"NGHXRG 2.6 ({d}), {args.size}² × {args.nframes}, {NOUT} outputs, "
             f"{args.darks} darks per case, exponent {args.exponent:g}"]
    for case in args.cases.split(","):
        params = {**DEFAULTS, **CASES[case]}
        draws, paths = [], []
        t0 = time.perf_counter()
        for k in range(args.darks):
            path = out / f"{case}_{args.size}_{k}.fits"
            draws.append(draw(module, pca0, args.size, args.nframes, params,
                              1000 * list(CASES).index(case) + k, path))
            paths.append(str(path))
        t_gen = time.perf_counter() - t0
        t0 = time.perf_counter()
        model = characterize(paths, Pipeline(cfg), exponent=args.exponent, pixels=False)
        t_char = time.perf_counter() - t0
        want = truth(params, draws, args.size)
        text = report(case, params, model, want, t_char)
        text[0] += f" (NGHXRG {t_gen:.0f} s for {args.darks} cubes)"
        print("\n".join(text), flush=True)
        lines.extend(text)
        if args.plot:
            from spherex_reduce.analysis.characterize.figure import plot_characterization

            plot = Path(args.plot)
            plot.mkdir(parents=True, exist_ok=True)
            plot_characterization(model).savefig(plot / f"{case}.png", dpi=100)
            spectra(model, case, params, text).write(plot / f"{case}-spectra.ecsv",
                                                     format="ascii.ecsv", overwrite=True)
            model.report().write(plot / f"{case}-report.ecsv", format="ascii.ecsv",
                                 overwrite=True)


if __name__ == "__main__":
    main()
