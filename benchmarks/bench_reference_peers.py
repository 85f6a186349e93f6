"""Reference correction against peers: NGHXRG 2.6's cases through our strategies and jwst's refpix.

Run: ``python benchmarks/bench_reference_peers.py [--nghxrg DIR] [--size 2048] [--nframes 10]
[--darks 4] [--cases white,c_pink,u_pink,acn,all] [--cubes DIR] [--floor-cases LIST]
[--no-jwst]`` (issue 34's measurement).

**Cubes.** NGHXRG's cases, drawn and read as ``bench_characterize_nghxrg.py`` draws and reads
them (imported: its `config`, `draw`, NGHXRG's clone and PCA-zero stand-in; 4 outputs read
``-->, <--, -->, <--``, a 4-pixel reference border, 100 kHz, ADU), on seeds of their own
(``1000 · case + 500 + k``), cached as ``DIR/CASE_SIZExFRAMES_K.fits`` (default
``/tmp/refpeers_cubes``).  NGHXRG always adds a fixed bias (``pca0 · bias_amp + bias_offset``
plus kTC noise, the first draw after the seed); the script recomputes it from the seed and
the template (`bias`), so that each dark is reduced **raw** (as written, uint16) and
**bias-subtracted** (minus that pattern: a perfect superbias).  For the floor, NGHXRG draws
each cube a second time on the same seed with every 1/f term ×1000, the white noise at
1e-30, the kTC noise at 0 (NGHXRG still draws its normals) and a 32768 offset (the same
random draws; uint16 steps of 0.001 ADU), which gives the cube's 1/f part exactly
(`one_over_f`).

**Methods**, every one ending in the same numpy least-squares slope per pixel over the
frames' start times (`slopes`), on the same exposure:

- ``uncorrected`` (``unchop`` alone) and ``floor: true row means``: the 1/f part's true
  mean over each output's light-sensitive columns of each row, frame and column parity,
  subtracted (no estimation noise: the best any per-row offset correction can do);
- ours, ``unchop`` then ``correct_reference``: ``mean``; ``plain mean`` (the same, σ = 1e30:
  unclipped); ``acn``; ``median``; ``mean``/``acn`` with ``side_columns: true`` (only the
  outer outputs have side columns: the one-line warning is reported); ``wiener`` without a
  noise model (the paper's electronics, refused for ADU at 100 kHz) and with the model
  ``characterize`` fits to the case's darks (``noise: MODEL.yaml``; with and without
  ``acn: true``, and with ``side_columns: true``: the side columns' mean over the outer
  outputs observes the drift common to every output at every row);
- jwst's refpix (``jwst.refpix.reference_pixels.correct_model``, the step's defaults:
  running median of the side columns over 11 rows, side gain 1, 3σ clip) with side columns
  and even/odd columns, side columns alone, even/odd alone.  jwst is installed once into its
  own venv (``~/.cache/spherex_reduce/jwst-VERSION``, never into this one) and run in a
  subprocess there (``jwst_refpix_peer.py``): each cube is written as a level-1b
  ``RampModel`` by jwst's datamodels, corrected, saved, and its ``SCI`` read back here.  Its
  amplifier and side-column table is that of a 2048² full frame, so jwst runs at
  ``--size 2048`` only (smaller sizes would be subarrays inside one amplifier).

**Measured** on the light-sensitive pixels of each slope image (ADU/s), averaged over the
darks: the band power in 0.03-0.13 rad/pixel (`~spherex_reduce.analysis.case.SpectrumMeasure`,
the paper's 5-20' band) over the white-only darks' (the ``white`` case uncorrected); the
rms over the outputs of each output's mean slope (its offset); the even/odd amplitude, the
power at the column Nyquist frequency (``|Σ (-1)^x s|² / n`` over each output's columns of
a row, averaged over rows and outputs); the sky transfer (`~spherex_reduce.analysis.sky`:
a ``k^-2`` field of 10× the white slope noise injected into the first bias-subtracted dark
as a ramp, ``P_cross / P_sky`` of the two reductions' difference over the band); the time
of the correction per exposure (ours: ``unchop`` + ``correct_reference`` in this process,
median over exposures; jwst: ``correct_model`` alone).  Each with the ratio to what issue
34's targets compare it with: on ``c_pink`` ≤ 0.4× jwst refpix with side columns and ≤ 2×
the floor; with ACN never above uncorrected and ≤ 0.5× its even/odd peak; raw offsets ≤ 1.1×
the plain mean's; time ≤ 2× ``mean``'s.  The band power of ``uncorrected`` and of the
``wiener`` methods is also forecast (`~spherex_reduce.analysis.forecast`, no random numbers)
for the fitted model taken as the scene (gain 1): measured over forecast, within 10 %.
"""

import argparse
import json
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

import bench_characterize_nghxrg as ngb
import numpy as np
from astropy import units as u
from astropy.io import fits
from astropy.nddata import CCDData

from spherex_reduce import Exposure
from spherex_reduce.analysis import forecast
from spherex_reduce.analysis.case import SpectrumMeasure
from spherex_reduce.analysis.characterize import characterize
from spherex_reduce.analysis.light import light_sensitive
from spherex_reduce.analysis.sky import inject_sky, measure_against_sky, sky_field
from spherex_reduce.core.errors import SpherexReduceError
from spherex_reduce.noise.variance import ls_weights
from spherex_reduce.reduce.pipeline import Pipeline

JWST_VERSION = "3.0.0"
JWST_VENV = Path.home() / ".cache" / "spherex_reduce" / f"jwst-{JWST_VERSION}"
JWST_WORKER = Path(__file__).with_name("jwst_refpix_peer.py")
#: jwst's refpix options run: name -> (label, options)
JWST_MODES = {
    "side_evenodd": ("jwst refpix: side + even/odd", {"odd_even_columns": True,
                                                      "use_side_ref_pixels": True}),
    "side": ("jwst refpix: side", {"odd_even_columns": False, "use_side_ref_pixels": True}),
    "evenodd": ("jwst refpix: even/odd", {"odd_even_columns": True,
                                          "use_side_ref_pixels": False}),
}
JWST_SIDE = JWST_MODES["side_evenodd"][0]
#: NGHXRG's bias (its mknoise defaults, passed explicitly so the script knows them)
BIAS = {"bias_amp": 500.0, "bias_offset": 5000.0, "ktc_noise": 29.0}
#: the 1/f-only redraw: every 1/f term times SCALE, on OFFSET, white and kTC off
SCALE, OFFSET, TINY = 1000.0, 32768.0, 1e-30
PINK_TERMS = ("c_pink", "u_pink", "acn", "pca0_amp")
#: the injected sky: P(k) ∝ k^SKY_INDEX, rms SKY_RMS times the white slope noise
SKY_INDEX, SKY_RMS = -2.0, 10.0
MODEL = "MODEL.yaml"
UNCORRECTED, FLOOR, MEAN, PLAIN = ("uncorrected", "floor: true row means", "mean",
                                   "plain mean (unclipped)")
#: ``wiener`` with the fitted model and the side columns (the common drift at every row)
SIDE = "wiener + model + side"
#: methods whose band power is also forecast from the fitted model
FORECAST = (UNCORRECTED, "wiener + model", SIDE)
#: targets of issue 34 (T_FORECAST: measured within this fraction of the forecast)
T_FORECAST = 0.10
T_JWST, T_FLOOR, T_PEAK, T_PLAIN, T_TIME, T_SKY = 0.4, 2.0, 0.5, 1.1, 2.0, 0.99


def ours(model):
    """Our methods: label -> ``correct_reference`` parameters (None: ``unchop`` alone)."""
    wiener = {"strategy": "wiener", "noise": str(model)}
    return {UNCORRECTED: None,
            MEAN: {"strategy": "mean"},
            PLAIN: {"strategy": "mean", "sigma": 1e30, "maxiters": 1},
            "acn": {"strategy": "acn"},
            "median": {"strategy": "median"},
            "mean + side_columns": {"strategy": "mean", "side_columns": True},
            "acn + side_columns": {"strategy": "acn", "side_columns": True},
            "wiener (no noise model)": {"strategy": "wiener"},
            "wiener + model": wiener,
            "wiener + model, acn": {**wiener, "acn": True},
            SIDE: {**wiener, "side_columns": True},
            "wiener + model + side, acn": {**wiener, "side_columns": True, "acn": True}}


def forecasts(model_path, methods, out):
    """Band power each linear method of ours is forecast to leave on the model's own darks
    (the `characterize` model as a scene, with gain 1: ADU counted as electrons), and the
    seconds it took: ``{label: band}``."""
    scene = out.with_name(out.stem + "_gain1.yaml")
    scene.write_text("gain: 1.0\n" + model_path.read_text())
    bands, notes = {}, []
    for label, params in methods.items():
        if label not in FORECAST:
            continue
        steps = [{"unchop": {}}]
        if params is not None:
            steps.append({"correct_reference": {**params, "noise": str(scene)}
                          if "noise" in params else params})
        steps.append({"fit_ramp": {}})
        t0 = time.perf_counter()
        bands[label] = float(forecast(str(scene), {"steps": steps}).meta["band_power"])
        notes.append(f"{label} {time.perf_counter() - t0:.1f} s")
    return bands, "forecasts of the characterize model (band power, ADU/s squared): " + (
        ", ".join(f"{k} {v:.4g}" for k, v in bands.items()) + "; times " + ", ".join(notes))


def pipeline(cfg, params):
    steps = ["unchop"] if params is None else ["unchop", {"correct_reference": params}]
    return Pipeline({**cfg, "steps": steps})


# -- cubes --------------------------------------------------------------------------------
def bias(pca0, seed, shape):
    """NGHXRG's bias pattern of the cube drawn on ``seed``: ``pca0 · bias_amp + bias_offset +
    ktc_noise · N(0, 1)``, the first draw of ``mknoise`` (float64)."""
    np.random.seed(seed)  # noqa: NPY002 (NGHXRG's global generator, as it draws)
    ktc = np.random.standard_normal(shape)  # noqa: NPY002
    return (pca0.astype(np.float64) * BIAS["bias_amp"] + BIAS["bias_offset"]
            + BIAS["ktc_noise"] * ktc)


def cubes(module, pca0, case, args, floor):
    """The case's darks: ``[(path, bias, one_over_f or None), ...]``, drawn once and cached."""
    params = {**ngb.DEFAULTS, **ngb.CASES[case], **BIAS}
    out = []
    for k in range(args.darks):
        seed = 1000 * list(ngb.CASES).index(case) + 500 + k
        path = Path(args.cubes) / f"{case}_{args.size}x{args.nframes}_{k}.fits"
        b = path.with_suffix(".bias.npy")
        if not (path.is_file() and b.is_file()):
            t0 = time.perf_counter()
            _, template = ngb.draw(module, pca0, args.size, args.nframes, params, seed, path,
                                   record=False)
            np.save(b, bias(template, seed, (args.size, args.size)))
            print(f"  NGHXRG {path.name}: {time.perf_counter() - t0:.0f} s", flush=True)
        pink = None
        if floor:
            pink = path.with_suffix(".pink.fits")
            if not pink.is_file():
                redraw = {**params, "rd_noise": TINY, "ktc_noise": 0.0, "bias_amp": 0.0,
                          "bias_offset": OFFSET, **{t: SCALE * params[t] for t in PINK_TERMS}}
                ngb.draw(module, pca0, args.size, args.nframes, redraw, seed, pink, record=False)
        out.append((path, np.load(b), pink))
    return out


def one_over_f(path):
    """The 1/f part of a cube (ADU, float64) from its redraw (`cubes`)."""
    data = fits.getdata(path)
    if data.min() == 0 or data.max() == 65535:
        sys.exit(f"{path}: the 1/f redraw reached uint16's range; lower SCALE")
    return (data.astype(np.float64) - OFFSET) / SCALE


def floor_means(pink, geometry):
    """The 1/f part's mean over each output's light-sensitive columns, per frame, row and
    column parity, on every column of that output and parity (``pink``'s shape)."""
    _, cols = light_sensitive(geometry)
    light = np.zeros(geometry.ncols, bool)
    light[cols] = True
    x = np.arange(geometry.ncols)
    channel = geometry.channel_of_column()
    out = np.empty_like(pink)
    for c in range(geometry.nchannels):
        for parity in (0, 1):
            group = (channel == c) & (x % 2 == parity)
            out[:, :, group] = pink[:, :, group & light].mean(axis=2, keepdims=True)
    return out


# -- measures -----------------------------------------------------------------------------
def slopes(cube, schedule):
    """One least-squares slope per pixel (ADU/s) over the frames' start times: the same fit
    for every method."""
    w = ls_weights(schedule.frame_starts.to_value(u.s))
    return np.tensordot(w, np.asarray(cube, dtype=np.float64), axes=(0, 0))


def measures(slope, geometry):
    """Band power, per-output offsets' rms and the even/odd peak of one slope image."""
    rows, cols = light_sensitive(geometry)
    img = slope[rows, cols]
    measured = SpectrumMeasure()(CCDData(img, unit="adu/s"))
    band = measured["band_power"].value
    channel = geometry.channel_of_column()[cols]
    x = np.arange(geometry.ncols)[cols]
    offsets, peaks = [], []
    for c in range(geometry.nchannels):
        s = img[:, channel == c]
        offsets.append(s.mean())
        sign = np.where(x[channel == c] % 2 == 0, 1.0, -1.0)
        peaks.append(np.mean((s @ sign) ** 2) / sign.size)
    offsets = np.asarray(offsets)
    return {"band": band, "offsets": float(np.sqrt(np.mean((offsets - offsets.mean()) ** 2))),
            "peak": float(np.mean(peaks)), "k": u.Quantity(measured["k"]).value,
            "power": u.Quantity(measured["power"]).value}


def spectra_table(case, results, white_band):
    """P(k) of each method on the bias-subtracted darks (mean over darks) over the white-only
    darks' band power: one column per method, for the judging page's figure."""
    from astropy.table import Table

    t = Table(meta={"case": case, "white_band_power": white_band,
                    "unit": "P(k) / white-only band power"})
    for (variant, label), ms in results.items():
        if variant != "bias-subtracted":
            continue
        if "k" not in t.colnames:
            t["k"] = ms[0]["k"]
            t["k"].unit = "rad/pixel"
        t[label] = np.mean([m["power"] for m in ms], axis=0) / white_band
    return t


def transfer(with_sky, without, sky, geometry):
    """The sky transfer over the band (`measure_against_sky`; ADU/s taken as e/s)."""
    light = light_sensitive(geometry)
    m = measure_against_sky(CCDData(with_sky[light], unit="electron/s"),
                            CCDData(without[light], unit="electron/s"), sky, light=light)
    return m["sky_transfer"]


# -- jwst ------------------------------------------------------------------------------------
def jwst_python():
    """The interpreter of jwst's venv, made (once) with ``pip install jwst==JWST_VERSION``."""
    py = JWST_VENV / "bin" / "python"
    check = [str(py), "-c", "import jwst; print(jwst.__version__)"]
    if py.is_file() and subprocess.run(check, capture_output=True, text=True).stdout.strip() \
            == JWST_VERSION:
        return py
    print(f"installing jwst {JWST_VERSION} into {JWST_VENV} (once)", flush=True)
    subprocess.run([sys.executable, "-m", "venv", str(JWST_VENV)], check=True)
    subprocess.run([str(py), "-m", "pip", "install", "-q", f"jwst=={JWST_VERSION}"], check=True)
    return py


def run_jwst(py, named, workdir):
    """jwst's refpix in every mode on each cube: ``{(name, label): (slope cube, seconds)}``
    and the versions.  ``named``: name -> (cube, schedule)."""
    workdir.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name, (cube, _) in named.items():
        paths[name] = workdir / f"{name}.fits"
        fits.PrimaryHDU(np.asarray(cube, np.float32)).writeto(paths[name], overwrite=True)
    request = workdir / "request.json"
    request.write_text(json.dumps({"cubes": [str(p) for p in paths.values()],
                                   "out": str(workdir / "out"),
                                   "modes": {m: opts for m, (_, opts) in JWST_MODES.items()}}))
    proc = subprocess.run([str(py), str(JWST_WORKER), str(request)], capture_output=True,
                          text=True)
    if proc.returncode:
        sys.exit(f"jwst's refpix failed:\n{proc.stderr[-3000:]}")
    lines = [json.loads(line) for line in proc.stdout.splitlines() if line.startswith("{")]
    versions, results = lines[0], {}
    by_path = {str(p): n for n, p in paths.items()}
    for rec in lines[1:]:
        name = by_path[rec["cube"]]
        sci = fits.getdata(rec["output"], "SCI")[0]
        results[(name, JWST_MODES[rec["mode"]][0])] = (
            slopes(sci, named[name][1]), rec["seconds"], rec["status"])
    return results, versions


# -- one case ----------------------------------------------------------------------------------
def run_case(case, darks, cfg, args, jwst_py):
    """Every method on the case's darks; returns (rows by variant, notes, versions)."""
    base = Pipeline(cfg)
    model_path = Path(args.cubes) / f"{case}_{args.size}x{args.nframes}.{MODEL}"
    t0 = time.perf_counter()
    model = characterize([str(p) for p, _, _ in darks], base, exponent=1.3, pixels=False)
    model_path.write_text(model.to_yaml())
    notes = [f"characterize ({len(darks)} darks, the same as reduced): "
             f"{time.perf_counter() - t0:.1f} s, {model_path}"]
    methods = ours(model_path)
    fc, line = forecasts(model_path, methods, model_path)
    notes.append(line)
    results = {}   # (variant, method) -> list of measures
    times, errors, warned = {}, {}, {}
    slope_of = {}  # (variant, method, k) -> slope, for the sky
    exposures = {}
    sky = None
    for k, (path, b, pink) in enumerate(darks):
        e = base.read(path)
        s = e.schedule
        g = s.geometry
        raw = np.asarray(e.data.data, dtype=np.float64)
        sub = raw - b[s.rows]
        exposures[("bias-subtracted", k)] = sub
        exposures[("raw", k)] = raw
        if k == 0:
            white_slope = ngb.DEFAULTS["rd_noise"] * np.sqrt(
                np.sum(ls_weights(s.frame_starts.to_value(u.s)) ** 2))
            sky = sky_field(g, SKY_RMS * white_slope, SKY_INDEX, seed=11)
            with_sky = inject_sky(Exposure.from_arrays(sub, s, unit=u.electron), sky)
            exposures[("sky", 0)] = np.asarray(with_sky.data.data)
        floor = None if pink is None else floor_means(one_over_f(pink), g)[:, s.rows]
        for variant in [v for (v, kk) in exposures if kk == k]:
            data = exposures[(variant, k)]
            exp = Exposure.from_arrays(data, s, unit=u.adu, header=e.header)
            for label, params in methods.items():
                if (variant, label) in errors:
                    continue
                with warnings.catch_warnings(record=True) as caught:
                    warnings.simplefilter("always")
                    try:
                        t0 = time.perf_counter()
                        out = pipeline(cfg, params).run(exp)
                        seconds = time.perf_counter() - t0
                    except SpherexReduceError as exc:
                        errors[(variant, label)] = str(exc).splitlines()[0]
                        continue
                for w in caught:
                    warned.setdefault(label, f"{w.category.__name__}: "
                                      + str(w.message).splitlines()[0])
                times.setdefault(label, []).append(seconds)
                slope_of[(variant, label, k)] = slopes(out.data.data, s)
                del out
            if floor is not None:
                slope_of[(variant, FLOOR, k)] = slopes(data - floor, s)
        if jwst_py is not None:
            named = {f"{v}_{kk}": (exposures[(v, kk)], s) for (v, kk) in exposures if kk == k}
            scratch = Path(args.cubes) / "jwst" / f"{case}_{k}"
            res, versions = run_jwst(jwst_py, named, scratch)
            shutil.rmtree(scratch, ignore_errors=True)  # its level-1b files and outputs: read
            versions = "peer versions: " + ", ".join(f"{n} {v}" for n, v in versions.items())
            if versions not in notes:
                notes.append(versions)
            for (name, label), (slope, seconds, status) in res.items():
                variant = name.rsplit("_", 1)[0]
                slope_of[(variant, label, k)] = slope
                times.setdefault(label, []).append(seconds)
                if status:
                    errors[(variant, label)] = f"refpix status {status} (skipped)"
        for key in [key for key in exposures if key[1] == k]:
            del exposures[key]
        # measures per variant and method, dark by dark: only the first dark's slopes (the
        # sky transfer's) are kept, so memory does not grow with --darks
        for key in [key for key in slope_of if key[2] == k]:
            if key[0] != "sky":
                results.setdefault(key[:2], []).append(measures(slope_of[key], g))
            if k != 0 or key[0] not in ("sky", "bias-subtracted"):
                del slope_of[key]
    sky_t = {label: transfer(slope_of[("sky", label, 0)], slope_of[("bias-subtracted", label, 0)],
                             sky, g)
             for (variant, label, k) in slope_of if variant == "sky"}
    notes.extend(f"{label}: warned: {msg}" for label, msg in warned.items())
    refused = {}
    for (variant, label), msg in errors.items():
        refused.setdefault((label, msg), []).append(variant)
    notes.extend(f"{label} ({', '.join(v)}): refused: {msg}" for (label, msg), v in refused.items())
    return results, sky_t, times, notes, fc


def summary(results, variant):
    """Mean (and standard error of the band power) of each method's measures."""
    out = {}
    for (v, label), ms in results.items():
        if v != variant:
            continue
        band = np.array([m["band"] for m in ms])
        err = band.std(ddof=1) / np.sqrt(band.size) if band.size > 1 else np.nan
        out[label] = {"band": band.mean(), "band_err": err,
                      "offsets": float(np.sqrt(np.mean([m["offsets"] ** 2 for m in ms]))),
                      "peak": float(np.mean([m["peak"] for m in ms]))}
    return out


def table(case, variant, results, sky_t, times, white_band, fc):
    s = summary(results, variant)
    if not s:
        return []
    ref = {"jwst": s.get(JWST_SIDE, {}).get("band"), "floor": s.get(FLOOR, {}).get("band"),
           "none": s.get(UNCORRECTED, {}),
           "plain": s.get(PLAIN, {}).get("offsets"),
           "time": np.median(times[MEAN]) if MEAN in times else None}

    def ratio(a, b):
        return "-" if a is None or b is None or not b else f"{a / b:.3g}"

    lines = [f"\n#### {case}, {variant}\n",
             "| method | band power / white-only | / jwst side+even/odd (≤ 0.4) | / floor (≤ 2) "
             "| / uncorrected (≤ 1 with ACN) | offsets rms, ADU/s | / plain mean (≤ 1.1 raw) "
             "| even/odd peak, (ADU/s)² | / uncorrected (≤ 0.5 with ACN) | sky transfer (≥ 0.99) "
             "| s per exposure | / mean (≤ 2) | / forecast (within 10 %) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for label, m in s.items():
        band = m["band"] / white_band
        err = m["band_err"] / white_band
        t = np.median(times[label]) if label in times else None
        sky = sky_t.get(label) if variant == "bias-subtracted" else None
        lines.append(
            f"| {label} | {band:.3g} ± {err:.2g} | {ratio(m['band'], ref['jwst'])} "
            f"| {ratio(m['band'], ref['floor'])} | {ratio(m['band'], ref['none'].get('band'))} "
            f"| {m['offsets']:.3g} | {ratio(m['offsets'], ref['plain'])} | {m['peak']:.3g} "
            f"| {ratio(m['peak'], ref['none'].get('peak'))} "
            f"| {'-' if sky is None else f'{sky:.4f}'} "
            f"| {'-' if t is None else f'{t:.3g}'} | {ratio(t, ref['time'])} "
            f"| {ratio(m['band'], fc.get(label))} |")
    return lines


def verdict(case, results, sky_t, times, fc):
    """One line per target of issue 34 that the case measures, for our best method."""
    sub, raw = summary(results, "bias-subtracted"), summary(results, "raw")
    mine = [m for m in sub if m not in (UNCORRECTED, FLOOR) and not m.startswith("jwst")]
    if not mine:
        return []
    best = min(mine, key=lambda m: sub[m]["band"])
    out = [f"best of ours on band power (bias-subtracted): {best}"]
    if case == "c_pink" and JWST_SIDE in sub:
        r = sub[best]["band"] / sub[JWST_SIDE]["band"]
        out.append(f"target ≤ {T_JWST}× {JWST_SIDE}'s band power: {r:.3g} "
                   f"({'met' if r <= T_JWST else 'not met'})")
    if case == "c_pink" and FLOOR in sub:
        r = sub[best]["band"] / sub[FLOOR]["band"]
        out.append(f"target ≤ {T_FLOOR}× the floor: {r:.3g} "
                   f"({'met' if r <= T_FLOOR else 'not met'})")
    if case == "c_pink" and SIDE in sub and SIDE in fc:
        r = sub[SIDE]["band"] / fc[SIDE]
        none = sub[UNCORRECTED]["band"] / fc[UNCORRECTED]
        out.append(f"target within {T_FORECAST:.0%} of our forecast for that model ({SIDE}): "
                   f"measured / forecast {r:.3g} "
                   f"({'met' if abs(r - 1) <= T_FORECAST else 'not met'}); the uncorrected "
                   f"darks / the model's forecast {none:.3g} (how well the model describes "
                   f"them), the gain over uncorrected measured / forecast {r / none:.3g}")
    if case == "c_pink" and best in sky_t:
        out.append(f"target sky transfer ≥ {T_SKY}: {sky_t[best]:.4f} "
                   f"({'met' if sky_t[best] >= T_SKY else 'not met'})")
    if {**ngb.DEFAULTS, **ngb.CASES[case]}["acn"] > 0 and UNCORRECTED in sub:
        for m in ("acn", "wiener + model, acn"):
            if m in sub:
                b = sub[m]["band"] / sub[UNCORRECTED]["band"]
                pk = sub[m]["peak"] / sub[UNCORRECTED]["peak"]
                out.append(f"ACN targets for {m}: band power {b:.3g}× uncorrected (≤ 1: "
                           f"{'met' if b <= 1 else 'not met'}), even/odd peak {pk:.3g}× "
                           f"(≤ {T_PEAK}: {'met' if pk <= T_PEAK else 'not met'})")
    if PLAIN in raw:
        worst = max((m for m in mine if m in raw and m != "median"),
                    key=lambda m: raw[m]["offsets"])
        r = raw[worst]["offsets"] / raw[PLAIN]["offsets"]
        out.append(f"raw offsets ≤ {T_PLAIN}× the plain mean's: {MEAN} "
                   f"{raw[MEAN]['offsets'] / raw[PLAIN]['offsets']:.3g}, worst of ours "
                   f"(median aside) {worst} {r:.3g}")
    if MEAN in times:
        tm = np.median(times[MEAN])
        slow = [f"{m} {np.median(times[m]) / tm:.2g}×" for m in mine
                if m in times and np.median(times[m]) > T_TIME * tm]
        out.append(f"time ≤ {T_TIME}× {MEAN}'s ({tm:.3g} s): "
                   + ("met by all of ours" if not slow else "not met by " + ", ".join(slow)))
    return out


def main():
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ngb.cube_arguments(p)
    p.add_argument("--floor-cases", default=",".join(ngb.CASES),
                   help="cases whose floor is measured (NGHXRG draws each cube twice)")
    p.add_argument("--cubes", default="/tmp/refpeers_cubes", help="where cubes are cached")
    p.add_argument("--no-jwst", action="store_true", help="leave jwst's refpix out")
    p.add_argument("--out", help="also write the tables (markdown) to this file")
    p.add_argument("--spectra", help="write the c_pink case's P(k) per method (ECSV)")
    args = p.parse_args()
    cases = args.cases.split(",")
    unknown = sorted(set(cases) - set(ngb.CASES))
    if unknown or args.darks < 2:
        sys.exit(f"unknown cases {unknown}; --darks must be at least 2")
    if "white" not in cases:
        cases.insert(0, "white")  # the band power's unit
    cases.sort(key=list(ngb.CASES).index)
    d, module, pca0 = ngb.peer(args.nghxrg, args.cubes)
    jwst_py = None
    head = [f"NGHXRG 2.6 ({d}), {args.size}² × {args.nframes}, {ngb.NOUT} "
            f"outputs, {args.darks} darks per case (seeds 1000·case + 500 + k), cubes in "
            f"{args.cubes}; band 0.03-0.13 rad/pixel"]
    if args.no_jwst:
        head.append("jwst refpix left out (--no-jwst)")
    elif args.size != 2048:
        head.append(f"jwst refpix left out: its amplifier table is a 2048² full frame's "
                    f"(--size {args.size})")
    else:
        jwst_py = jwst_python()
    print("\n".join(head), flush=True)
    cfg = ngb.config(args.size, args.nframes)
    white_band = None
    lines = list(head)
    floors = set(args.floor_cases.split(","))
    for case in cases:
        t0 = time.perf_counter()
        print(f"\n{case}: drawing/reading cubes", flush=True)
        darks = cubes(module, pca0, case, args, case in floors)
        results, sky_t, times, notes, fc = run_case(case, darks, cfg, args, jwst_py)
        if case == "white":
            white_band = summary(results, "bias-subtracted")[UNCORRECTED]["band"]
            notes.append(f"white-only band power (uncorrected, bias-subtracted): "
                         f"{white_band:.4g} (ADU/s)² pix²")
        params = {**ngb.DEFAULTS, **ngb.CASES[case]}
        text = [f"\n### {case}: " + ", ".join(f"{k} {v:g}" for k, v in params.items())
                + f" ({time.perf_counter() - t0:.0f} s)"]
        for variant in ("bias-subtracted", "raw"):
            text.extend(table(case, variant, results, sky_t, times, white_band, fc))
        if args.spectra and case == "c_pink":
            spectra_table(case, results, white_band).write(args.spectra, format="ascii.ecsv",
                                                           overwrite=True)
        text.append("")
        text.extend(f"- {n}" for n in verdict(case, results, sky_t, times, fc) + notes)
        print("\n".join(text), flush=True)
        lines.extend(text)
        if args.out:
            Path(args.out).write_text("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
