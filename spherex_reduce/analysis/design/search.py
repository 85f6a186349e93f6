"""Design a readout: the schedule of least forecast band power within a frame-time budget.

`design_readout` searches, for a `~spherex_reduce.analysis.design.file.Design`:

1. *families*: every order of `~spherex_reduce.analysis.design.row_orders.family_orders`
   (skips, nested skips, radical-inverse and golden-ratio orders) at the
   baseline's timing (``c``, ``r`` and reference placement);
2. *timing*: for the best ``finalists`` orders, every ``c`` (phantom reads),
   ``r`` (reference reads) and reference placement (``distributed``,
   ``repeated``) whose reads fit in the frame time;
3. *local search*: from the best so far, ``iterations`` random moves of the
   active rows' order (swap two blocks of reads, reverse one, move one),
   each kept if it lowers the objective.

The objective is `~spherex_reduce.analysis.forecast`'s band power of the
image the design's pipeline makes (exact, no random numbers), with the frame
time fixed by the budget and every active row read once per frame.  The best
schedule is then compared with the baseline (the paper's S = 24, r = 32
distributed, c = 4 at the same frame time): forecast P(k) per bin and per
noise component, and a paired Monte Carlo (the same seeds for both
schedules, reduced with the design's pipeline, band power measured by
`~spherex_reduce.analysis.case.SpectrumMeasure`), which stops once the
standard error of its gain is ``gain_error`` (1 percentage point by default).
"""

import time
from dataclasses import dataclass, replace

import numpy as np
from astropy.table import Table
from threadpoolctl import threadpool_limits

from ...core._text import plural
from ...core.errors import ConfigError, SpherexReduceError
from ...core.readout.schedule import chopped_order
from ...reduce.pipeline import as_pipeline
from ...reduce.progress import Progress
from ...simulation import simulate
from ...simulation.scene import load_scene
from ..case import SpectrumMeasure, run_case
from ..forecast.engine import band_power_forecast, forecast_tables
from ..light import light_sensitive_image
from .file import MIN_PAIRS, load_design
from .row_orders import explicit_order, family_orders

__all__ = ["Candidate", "DesignResult", "design_readout", "plot_design"]

#: Readout keys a design sets itself (timing and order): not taken from the scene.
_DESIGNED = ("skip", "ref_reads", "ref_mode", "phantom_reads", "order", "frame_time",
             "frame_overhead")


@dataclass(frozen=True)
class Candidate:
    """One schedule tried: its family and label, timing, active-row order and band power.

    ``permutation[t]`` is the active row (from the first active row) read in slot ``t``;
    ``skip``: the skip ``S`` whose order it is (written as ``skip``, not as an explicit
    order), or None; ``band_power``: its forecast band power, (e/s)² pix².
    """

    stage: str
    family: str
    label: str
    phantom_reads: int
    ref_reads: int
    ref_mode: str
    permutation: object
    skip: object
    band_power: float


@dataclass
class DesignResult:
    """What `design_readout` found: ``best`` and ``baseline`` `Candidate`, their scenes
    (dicts that `~spherex_reduce.simulation.load_scene` takes, with the scene terms the
    search left out given back: `~spherex_reduce.analysis.design.file.Design.carried`),
    every candidate tried, the report table and the seconds spent per stage."""

    best: Candidate
    baseline: Candidate
    best_scene: dict
    baseline_scene: dict
    candidates: list
    report: Table
    seconds: dict


def design_readout(design, progress=False):
    """Search the readout of least forecast band power (see the module notes).

    Parameters
    ----------
    design : `~spherex_reduce.analysis.design.file.Design`, dict, YAML text or path
        What to search (`~spherex_reduce.analysis.design.file.load_design`).
    progress : bool
        Per stage (row orders, timings, local-search moves, paired realisations),
        its expected duration on stdout once its first step is done and a
        progress bar on a terminal (stderr), as
        `~spherex_reduce.reduce.progress.Progress` shows them.

    Returns
    -------
    `DesignResult`
        ``report``: per k bin, the forecast P(k) of the baseline and the best
        schedule (total, ``ratio``, and per component), with the paired Monte
        Carlo's mean P(k) when it ran; its ``meta`` holds the band powers,
        the gain (1 - best / baseline) in total and per component, the Monte
        Carlo's gain and standard error, both schedules and the candidates.

    Raises
    ------
    ConfigError
        An invalid design, a baseline that does not fit the budget, or one whose
        forecast band power is 0 (nothing to minimise).

    Examples
    --------
    >>> from spherex_reduce.analysis.design.search import design_readout
    >>> res = design_readout({
    ...     "scene": {"geometry": {"nrows": 40, "ncols": 16, "nchannels": 2, "ref_border": 4},
    ...               "readout": {"nframes": 4},
    ...               "noise": {"components": [{"name": "f", "beta": 1e-2}]}},
    ...     "pipeline": "none", "band": {"kmin": 0.2, "kmax": 1.0},
    ...     "baseline": {"skip": 4, "ref_reads": 8},
    ...     "search": {"families": ["skip"], "skips": [1, 2, 4], "phantom_reads": [4],
    ...                "ref_reads": [8], "ref_modes": ["distributed"], "iterations": 0},
    ...     "realizations": 0})
    >>> [c.label for c in res.candidates], res.best.label
    (['S=4', 'S=1', 'S=2'], 'S=4')
    >>> res.report.meta["gain"]   # the best is the baseline here
    0.0
    """
    d = design if hasattr(design, "families") else load_design(design)
    if d.pipeline is not None:  # read once, not once per schedule
        d = replace(d, pipeline=as_pipeline(d.pipeline))
    # the forecasts' and the simulations' matrix products are small (tens by thousands):
    # BLAS threads only spin (the paper's case: 75 s of CPU for 57 s with them, 57 s for 53 s
    # without, on 2 cores)
    with threadpool_limits(limits=1, user_api="blas"):
        return _search(d, progress)


def _search(d, progress):
    """`design_readout` of a validated `~spherex_reduce.analysis.design.file.Design`."""
    base = load_scene(d.scene)
    g = base.schedule.geometry
    readout = {k: v for k, v in (d.scene.get("readout") or {}).items() if k not in _DESIGNED}
    scene_of = _SceneMaker(d, readout, g, base.schedule.row_overhead)
    n = g.n_active_rows
    objective = _Objective(d, scene_of)
    seconds = {}
    t0 = time.perf_counter()
    b = d.baseline
    if not scene_of.fits(g, b.phantom_reads, b.ref_reads):
        raise ConfigError(f"{d.label}: budget.frame_time: {d.frame_time:g} s is too short for "
                          f"the baseline's reads ({plural(n + b.ref_reads, 'read')} with "
                          f"c = {b.phantom_reads})")
    baseline = objective("baseline", "skip", f"S={b.skip}", b.phantom_reads,
                         b.ref_reads, b.ref_mode, chopped_order(n, b.skip),
                         b.skip)
    if not baseline.band_power > 0:
        raise ConfigError(f"{d.label}: noise: the baseline's forecast band power is "
                          f"{baseline.band_power:g} (no noise in the band): nothing to "
                          "minimise")
    objective.refuse = True
    orders = family_orders(n, d.families, d.skips)
    with Progress(len(orders), "row order", progress) as bar:
        for family, label, perm in orders:
            objective("families", family, label, b.phantom_reads, b.ref_reads,
                      b.ref_mode, perm, int(label[2:]) if family == "skip" else None)
            bar.done()
    seconds["families"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    timings = [(c, r, m) for c in d.phantom_reads for r in d.ref_reads for m in d.ref_modes
               if scene_of.fits(g, c, r) and (r == 0 or g.border.rows) and
               (r > 0 or m == d.ref_modes[0])]
    finalists = _best_orders(objective.tried, d.finalists)
    # the first forecast computes the slope covariance the later ones share: not the timer
    with Progress(len(finalists) * len(timings), "timing", progress, warmup=1) as bar:
        for cand in finalists:
            for c, r, m in timings:
                if objective("timing", cand.family, cand.label, c, r, m, cand.permutation,
                             cand.skip) is None:
                    bar.skip()  # refused at once (no reference reads)
                else:
                    bar.done()
    seconds["timing"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    rng = np.random.default_rng(d.search_seed)
    best = min(objective.tried, key=lambda c: c.band_power)
    with Progress(d.iterations, "local-search move", progress) as bar:
        for i in range(d.iterations):
            perm = _move(np.asarray(best.permutation), rng)
            cand = objective("local", best.family, f"{best.label.split(' +')[0]} +{i + 1}",
                             best.phantom_reads, best.ref_reads, best.ref_mode, perm)
            if cand is not None and cand.band_power < best.band_power:
                best = cand
            bar.done()
    seconds["local"] = time.perf_counter() - t0
    best = min(objective.tried, key=lambda c: c.band_power)
    t0 = time.perf_counter()
    best_scene, base_scene = scene_of(best), scene_of(baseline)
    report = _report(d, best, baseline, best_scene, base_scene, objective.tried)
    seconds["forecast_report"] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if d.realizations:
        _confirm(d, report, best_scene, base_scene, progress)
    seconds["monte_carlo"] = time.perf_counter() - t0
    report.meta["seconds"] = {k: round(v, 3) for k, v in seconds.items()}
    report.meta["evaluations"] = len(objective.tried)
    report.meta["refused"] = objective.refused
    return DesignResult(best, baseline, d.carried(best_scene), d.carried(base_scene),
                        objective.tried, report, seconds)


class _SceneMaker:
    """The scene (a dict) of a candidate: the design's scene with its timing and order."""

    def __init__(self, design, readout, geometry, row_overhead):
        self.d = design
        self.readout = readout
        self.g = geometry
        self.row_overhead = row_overhead

    def fits(self, g, c, r):
        """Whether ``n_active + r`` row reads of ``c + width + row_overhead`` samples fit in
        the budget's frame time."""
        samples = round(self.d.frame_time * g.pixel_rate)
        return (g.n_active_rows + r) * (c + g.channel_width + self.row_overhead) <= samples

    def __call__(self, cand):
        ro = {**self.readout, "phantom_reads": int(cand.phantom_reads),
              "frame_time": float(self.d.frame_time)}
        if cand.skip is not None:
            ro.update(skip=int(cand.skip), ref_reads=int(cand.ref_reads),
                      ref_mode=cand.ref_mode)
        else:
            ro["order"] = explicit_order(self.g, cand.permutation, cand.ref_reads,
                                         cand.ref_mode)
        return {**self.d.scene, "readout": ro}


class _Objective:
    """The forecast band power of a candidate, per component; every candidate is kept."""

    def __init__(self, design, scene_of):
        self.d = design
        self.scene_of = scene_of
        self.tried = []
        self.refused = []  # candidates the pipeline cannot reduce (e.g. r = 0 for a reference
        self.refuse = False  # correction), skipped once refuse is set
        self._seen = {}

    def __call__(self, stage, family, label, c, r, mode, perm, skip=None):
        perm = np.asarray(perm, dtype=int)
        key = (c, r, mode if r else "", perm.tobytes())
        if key in self._seen:
            return self._seen[key]
        cand = Candidate(stage, family, label, int(c), int(r), mode, perm, skip, None)
        try:
            power = band_power_forecast(self.scene_of(cand), self.d.pipeline, self.d.kmin,
                                        self.d.kmax)
        except SpherexReduceError as exc:
            if not self.refuse:
                raise
            self.refused.append(f"{label}, c={c}, r={r} {mode}: {exc}")
            self._seen[key] = None
            return None
        cand = Candidate(stage, family, label, int(c), int(r), mode, perm, skip, power)
        self._seen[key] = cand
        self.tried.append(cand)
        return cand


def _best_orders(tried, count):
    """The ``count`` best candidates of distinct orders."""
    out, seen = [], set()
    for cand in sorted(tried, key=lambda c: c.band_power):
        key = cand.label
        if key not in seen:
            seen.add(key)
            out.append(cand)
        if len(out) == count:
            break
    return out


def _move(perm, rng):
    """A new order: two blocks of reads swapped, one reversed, or one moved (a copy)."""
    n = perm.size
    if n < 2:
        return perm.copy()
    length = int(rng.integers(1, max(1, n // 8) + 1))
    kind = int(rng.integers(3))
    out = perm.copy()
    if kind == 0 and 2 * length <= n:
        i, j = np.sort(rng.choice(n - 2 * length + 1, 2, replace=True))
        j = j + length
        out[i:i + length], out[j:j + length] = perm[j:j + length], perm[i:i + length]
    elif kind == 1:
        i = int(rng.integers(n - length + 1))
        out[i:i + length] = perm[i:i + length][::-1]
    else:
        i = int(rng.integers(n - length + 1))
        rest = np.concatenate([perm[:i], perm[i + length:]])
        j = int(rng.integers(rest.size + 1))
        out = np.concatenate([rest[:j], perm[i:i + length], rest[j:]])
    return out


def _report(d, best, baseline, best_scene, base_scene, tried):
    """Per k bin: the forecast P(k) of both schedules, total and per component."""
    measure = {"kmin": d.kmin, "kmax": d.kmax, "bins": d.bins}
    band = {"kmin": d.kmin, "kmax": d.kmax, "bins": [d.kmin, d.kmax]}
    fb, b = forecast_tables(best_scene, d.pipeline, [measure, band])
    fa, a = forecast_tables(base_scene, d.pipeline, [measure, band])
    a, b = _band_parts(a), _band_parts(b)
    report = Table()
    for name in ("k", "theta", "k_lo", "k_hi"):
        report[name] = fa[name]
    report["power_baseline"] = fa["power"]
    report["power_best"] = fb["power"]
    report["ratio"] = np.asarray(fb["power"] / fa["power"], dtype=float)
    comps = [c[len("power_"):] for c in fa.colnames if c.startswith("power_")
             and c != "power_err"]
    for c in comps:
        report[f"power_baseline_{c}"] = fa[f"power_{c}"]
        report[f"power_best_{c}"] = fb[f"power_{c}"]
    drop = a["total"] - b["total"]
    report.meta.update({
        "design": d.label,
        "pipeline": fa.meta["pipeline"],
        "band_kmin": d.kmin, "band_kmax": d.kmax, "frame_time": d.frame_time,
        "band_unit": str(fa["power"].unit),
        "baseline": _describe(baseline, load_scene(base_scene)),
        "best": _describe(best, load_scene(best_scene)),
        "band_power_baseline": a["total"], "band_power_best": b["total"],
        "gain": 1 - b["total"] / a["total"],
        "band_power_components": {c: {"baseline": a[c], "best": b[c],
                                      "share_of_gain": (a[c] - b[c]) / drop if drop else 0.0}
                                  for c in comps},
        "candidates": [{"stage": c.stage, "family": c.family, "label": c.label,
                        "phantom_reads": c.phantom_reads, "ref_reads": c.ref_reads,
                        "ref_mode": c.ref_mode, "band_power": c.band_power} for c in tried],
    })
    return report


def _band_parts(table):
    """``{'total': band power, component: its band power}`` of a one-bin forecast."""
    out = {"total": float(np.asarray(table["power"])[0])}
    out.update({c[len("power_"):]: float(np.asarray(table[c])[0]) for c in table.colnames
                if c.startswith("power_") and c != "power_err"})
    return out


def _describe(cand, scene):
    return {"family": cand.family, "label": cand.label, "summary": scene.schedule.summary(),
            "phantom_reads": cand.phantom_reads, "ref_reads": cand.ref_reads,
            "ref_mode": cand.ref_mode}


def _confirm(d, report, best_scene, base_scene, progress):
    """The paired Monte Carlo: both scenes simulated with seeds ``seed, seed + 1, ...``,
    reduced and measured, up to ``d.realizations`` pairs, stopping once `MIN_PAIRS` have run
    and the gain's standard error is at most ``d.gain_error``; adds the mean P(k) to
    ``report`` and the band powers, the gain and its standard error to its meta."""
    measure = SpectrumMeasure(kmin=d.kmin, kmax=d.kmax, bins=d.bins)
    runs = {"baseline": [], "best": []}
    until = (f"stopping once the gain's standard error is <= {d.gain_error:g}, after "
             f"{MIN_PAIRS} at least" if d.gain_error and d.realizations > MIN_PAIRS else None)
    with Progress(d.realizations, "paired realisation", progress, until=until) as bar:
        for i in range(d.realizations):
            for name, scene in (("baseline", base_scene), ("best", best_scene)):
                runs[name].append(_measured(scene, d.pipeline, measure, d.seed + i))
            bar.done()
            a, b = (np.array([m["band_power"].value for m in runs[k]]) for k in runs)
            ratio, err = _paired_gain(a, b)
            if until and a.size >= MIN_PAIRS and err <= d.gain_error:
                break
    unit = report["power_baseline"].unit
    for name in runs:  # the measure's spectrum has the forecast's bins (empty ones left out)
        power = np.mean([np.asarray(m["spectrum"]["power"]) for m in runs[name]], axis=0)
        report[f"power_mc_{name}"] = power * unit
    report.meta["monte_carlo"] = {
        "realizations": int(a.size), "most_realizations": d.realizations,
        "gain_error_target": d.gain_error, "seeds": [d.seed, d.seed + int(a.size) - 1],
        "band_power_baseline": float(a.mean()),
        "band_power_baseline_err": float(a.std(ddof=1) / np.sqrt(a.size)) if a.size > 1
        else None,
        "band_power_best": float(b.mean()),
        "band_power_best_err": float(b.std(ddof=1) / np.sqrt(b.size)) if b.size > 1 else None,
        "gain": float(1 - ratio), "gain_err": float(err),
    }


def _paired_gain(a, b):
    """``(mean b / mean a, standard error of 1 - that ratio)`` of paired band powers (the
    delta method: the scatter of ``b - ratio a``); the error is NaN for one pair."""
    ratio = b.mean() / a.mean()
    if a.size < 2:
        return ratio, np.nan
    return ratio, np.std(b - ratio * a, ddof=1) / np.sqrt(a.size) / a.mean()


def _measured(scene, pipeline, measure, seed):
    """The measure of one realisation of a scene's slope image, reduced by ``pipeline``."""
    if pipeline is None:
        return measure(light_sensitive_image(simulate(scene, mode="slopes", seed=seed)))
    return run_case(scene, pipeline, measure, seed=seed, mode="slopes").measurement


def plot_design(report):
    """Band power of every candidate by stage and family, and P(k) of best and baseline.

    Parameters
    ----------
    report : `~astropy.table.Table`
        The ``report`` of a `DesignResult`, or the ECSV ``--report`` wrote.

    Returns
    -------
    `matplotlib.figure.Figure`
    """
    from matplotlib.figure import Figure

    from ...io.plotting import unit_label

    rep = report
    meta = rep.meta
    unit = unit_label(rep["power_baseline"].unit)
    fig = Figure(figsize=(12, 4.8))
    ax, bx = fig.subplots(1, 2)
    groups = {}
    cands = meta["candidates"]
    for i, c in enumerate(cands):
        key = c["family"] if c["stage"] == "families" else c["stage"]
        groups.setdefault(key, []).append((i, c["band_power"]))
    for key, pts in groups.items():
        x, y = np.array(pts).T
        ax.plot(x, y, "o", ms=3, label=key)
    base, best = meta["baseline"], meta["best"]
    ax.axhline(meta["band_power_baseline"], color="k", ls="--",
               label=f"paper's: {base['label']}, c={base['phantom_reads']}, "
                     f"r={base['ref_reads']}")
    ibest = int(np.argmin([c["band_power"] for c in cands]))
    ax.plot([ibest], [cands[ibest]["band_power"]], "r*", ms=14,
            label=f"best: {best['label']}, c={best['phantom_reads']}, r={best['ref_reads']}")
    ax.set_yscale("log")
    ax.set_xlabel("evaluation (families, then timing, then local search)")
    ax.set_ylabel(f"forecast band power [{unit}]")
    ax.set_title(f"{plural(len(cands), 'schedule')} searched")
    ax.legend(fontsize=7)
    k = np.asarray(rep["k"])
    for name, color in (("baseline", "k"), ("best", "r")):
        bx.loglog(k, np.asarray(rep[f"power_{name}"]), color=color, label=f"forecast, {name}")
        if f"power_mc_{name}" in rep.colnames:
            bx.loglog(k, np.asarray(rep[f"power_mc_{name}"]), "o", ms=3, color=color,
                      label=f"Monte Carlo, {name}")
    bx.axvspan(rep.meta["band_kmin"], rep.meta["band_kmax"], color="0.9", zorder=0,
               label="band")
    bx.set_xlabel("k [rad/pixel]")
    bx.set_ylabel(f"P(k) [{unit}]")
    gain = meta["gain"]
    mc = meta.get("monte_carlo")
    title = f"gain {100 * gain:.1f} % (forecast)"
    if mc:
        title += f", {100 * mc['gain']:.1f} ± {100 * mc['gain_err']:.1f} % (Monte Carlo)"
    bx.set_title(title)
    bx.legend(fontsize=7)
    fig.tight_layout()
    return fig
