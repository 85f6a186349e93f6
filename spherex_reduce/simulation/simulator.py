"""The built-in simulator: scene -> raw ramps or a slope image, in readout order."""

import json
import logging

import numpy as np
from astropy import units as u
from astropy.io import fits

from ..core.errors import ConfigError
from ..core.exposure import Exposure
from ..io import atomic_output, write, write_frames
from ..reduce.plugins import get_registry
from ..reduce.progress import terminal_bar
from ..reduce.step import Simulator
from .engine import NoiseEngine
from .grouping import average_groups, read_schedule
from .scene import load_scene
from .synthesis import rng_for
from .telegraph import ReferenceTelegraph, gamma_values, population_values

__all__ = ["SpherexSimulator", "simulate", "simulate_to_fits"]

log = logging.getLogger("spherex_reduce")
TIER_SIGNAL, TIER_HOT, TIER_RTN, TIER_RTN_REFERENCE, TIER_DARK = 100, 101, 102, 103, 104
#: The first key of every generator drawn from a scene's ``population_seed``.
TIER_POPULATION = 105
#: The generator of the light-sensitive pixels' own white read noise.
TIER_ACTIVE_WHITE = 106


class SpherexSimulator(Simulator):
    """The paper's noise model (Table 2) placed on the readout schedule.

    Registered under the name ``spherex`` by the ``simulation`` built-in
    plugin; a scene selects another registered simulator with
    ``synthesis: {simulator: NAME}``.
    """

    name = "spherex"

    def simulate(self, scene, *, mode=None, seed=None):
        return _simulate(scene, mode=mode, seed=seed)


def _prepare(scene, mode, seed):
    sc = load_scene(scene) if not hasattr(scene, "schedule") else scene
    mode = sc.mode if mode is None else mode
    sc.check_mode(mode)
    seed = sc.seed if seed is None else seed
    if isinstance(seed, (int, np.integer)) and seed < 0:
        raise ConfigError(f"seed: must be a non-negative integer, got {seed}")
    if seed is None:
        seed = np.random.SeedSequence().entropy
        log.info("simulate: no seed given; using %d", seed)
    synth = dict(sc.synthesis)
    padding = synth.get("padding")
    if padding is None:
        padding = 1.0 if synth.get("method") == "random_phase" else 16.0
    engine = NoiseEngine(read_schedule(sc.schedule), sc.components, seed, method=synth.get("method",
                         "gaussian"), padding=padding, dtype=synth.get("dtype", "float32"))
    return sc, mode, seed, engine


def _header(sc, mode, seed, engine):
    h = fits.Header()
    h["SIMULATR"] = ("spherex", "simulator that made this exposure")
    h["SIMMODE"] = (mode, "ramps or slopes")
    if isinstance(seed, np.random.SeedSequence):
        seed_text = f"{seed.entropy} spawn_key {list(seed.spawn_key)}"
    else:
        seed_text = str(seed)
    h["SIMSEED"] = (seed_text, "seed of the SeedSequence")
    h["SIMMETH"] = (engine.method, "Fourier amplitudes: gaussian or random_phase")
    h["SIMPAD"] = (engine.padding, "low-frequency synthesis length / exposure")
    if mode == "slopes":
        h["SIMROUTE"] = (engine.slope_route, "slopes drawn exactly or from synthesised tiers")
    for c in sc.components:
        h.add_history(f"noise {json.dumps(c.to_dict())}")
    h.add_history(f"scene {json.dumps(sc.terms.to_dict(), default=str)}")
    if sc.unit != u.electron:
        h["SIMGAIN"] = (sc.gain, "e-/adu of the scene in adu (its shot noise)")
    return h


def simulate(scene=None, *, mode=None, seed=None, registry=None):
    """Simulate a scene with the registered simulator it names (``spherex`` by default).

    Parameters
    ----------
    scene : str, path, dict or None
        Scene YAML file, YAML text or mapping (see :func:`load_scene`); None
        for the paper's case.
    mode : {'slopes', 'ramps'}, optional
        Overrides ``output.mode``.
    seed : int or `numpy.random.SeedSequence`, optional
        Overrides ``seed``; the same scene and seed give the same result.
    registry : `~spherex_reduce.reduce.plugins.Registry`, optional
        Where to look up the simulator (plugins included by default).

    Returns
    -------
    `~spherex_reduce.Exposure`
        ``ramps``: raw frames ``(N, reads, columns)`` in the scene's unit
        (electrons, or adu for a scene with ``unit: adu``: its numbers are taken
        as they are, the gain sets the shot noise of its currents), readout
        order, with phantom values ``(N, reads, channels)``.  ``slopes``: the
        least-squares slope image ``(reads, columns)`` in that unit per second,
        readout order, with phantom slopes ``(reads, channels)``.

    Examples
    --------
    >>> from spherex_reduce import simulate
    >>> scene = {"geometry": {"nrows": 32, "ncols": 32, "nchannels": 2, "ref_border": 2},
    ...          "readout": {"skip": 4, "ref_reads": 4, "nframes": 5, "phantom_reads": 2}}
    >>> e = simulate(scene, seed=1)
    >>> e.shape, e.unit, e.phantom.shape
    ((32, 32), Unit("electron / s"), (32, 2))
    >>> simulate(scene, seed=1, mode="ramps").shape
    (5, 32, 32)
    """
    sc = load_scene(scene) if not hasattr(scene, "schedule") else scene
    name = sc.synthesis.get("simulator", "spherex")
    if name == "spherex" and registry is None:
        return _simulate(sc, mode=mode, seed=seed)
    if registry is None:
        registry = get_registry()
    return registry.simulator(name)().simulate(sc, mode=mode, seed=seed)


def _simulate(scene, *, mode=None, seed=None):
    sc, mode, seed, engine = _prepare(scene, mode, seed)
    header = _header(sc, mode, seed, engine)
    s = sc.schedule
    if mode == "slopes":
        data, phantom = engine.slopes()
        terms = _Terms(sc, engine)
        terms.add_slopes(data, phantom)
        return Exposure.from_arrays(data, s, unit=sc.unit / u.s,
                                    phantom=None if phantom is None else
                                    phantom.astype(engine.dtype), header=header)
    cube = np.empty((s.nframes, s.n_reads, s.geometry.ncols), dtype=engine.dtype)
    ph = np.empty((s.nframes, s.n_reads, s.geometry.nchannels), dtype=engine.dtype) \
        if s.phantom_reads else None
    for k, (frame, phantom) in enumerate(average_groups(_frames(sc, engine), s)):
        cube[k] = frame
        if ph is not None:
            ph[k] = phantom
    return Exposure.from_arrays(cube, s, unit=sc.unit, phantom=ph, header=header)


def _frames(sc, engine):
    terms = _Terms(sc, engine)
    for k, (frame, phantom) in enumerate(engine.frames()):
        terms.add_frame(k, frame, phantom)
        yield frame, phantom


class _Terms:
    """Scene terms: dark current, hot pixels, photocurrent, leakage, telegraph noise, the
    light-sensitive pixels' own white read noise.

    The pixel populations (hot and telegraph pixels, per-pixel currents, steps and
    rates) come from `_population` generators: the scene's ``population_seed`` when it
    has one, else the simulation's seed; what changes from read to read (shot noise,
    telegraph states) always from the simulation's seed.
    """

    def __init__(self, sc, engine):
        self.t = t = sc.terms
        self.e = engine
        s = sc.schedule
        g = s.geometry
        # shot noise of a charge in the scene's unit: Poisson in electrons, then back
        self.shot = 1.0 if sc.unit == u.electron else 1.0 / sc.gain if sc.gain else None
        self.active = (~s.is_reference)[:, None] & (~g.reference_column_mask())[None, :]
        self.tau = s.pixel_samples() / g.pixel_rate  # s within frame
        self.tframe = s.frame_samples / g.pixel_rate
        rate = np.where(self.active, t.dark_current + t.photocurrent, 0.0)
        if t.dark_current_spread > 0:
            rng = self._population(TIER_DARK)
            dark = gamma_values(rng, t.dark_current, t.dark_current_spread, rate.shape)
            rate = np.where(self.active, dark + t.photocurrent, 0.0)
        if t.hot_pixel_fraction > 0:
            rng = self._population(TIER_HOT)
            hot = (rng.random(rate.shape) < t.hot_pixel_fraction) & self.active
            excess = t.hot_pixel_current
            if t.hot_pixel_current_spread > 0:
                excess = np.zeros(rate.shape)
                excess[hot] = gamma_values(rng, t.hot_pixel_current,
                                           t.hot_pixel_current_spread, int(hot.sum()))
            rate = rate + hot * excess
        self.rate = rate if np.any(rate) else None
        self.charge = None
        self.rtn, self.rtn_reference = [], []
        for i, r in enumerate(t.telegraphs):
            if not r.on:
                continue
            key = (TIER_RTN,) if i == 0 else (TIER_RTN, i)
            if r.pixels in ("active", "all"):  # read once per frame: switched frame to frame
                pop = self._population(*key)
                noise = pop if t.population_seed is None else rng_for(engine.entropy, *key)
                idx = np.flatnonzero((pop.random(rate.size) < r.fraction)
                                     & self.active.ravel())
                amp, rates = population_values(pop, r, idx.size)
                state = noise.random(idx.size) < 0.5
                self.rtn.append([idx, noise, amp, (1 - np.exp(-2 * rates * self.tframe)) / 2,
                                 state])
            if r.pixels in ("reference", "all"):  # seen at each of their reads
                key = (TIER_RTN_REFERENCE,) if i == 0 else (TIER_RTN_REFERENCE, i)
                noise = rng_for(engine.entropy, *key)
                pop = None if t.population_seed is None else self._population(*key)
                self.rtn_reference.append(ReferenceTelegraph(
                    s, r.fraction, r.amplitude, r.rate, noise, population=pop,
                    amplitude_spread=r.amplitude_spread, rate_spread=r.rate_spread))
        s_ph = s.phantom_samples()
        self.tau_ph = (s_ph.mean(axis=1) / g.pixel_rate) if s.phantom_reads else None
        self.sig_rng = rng_for(engine.entropy, TIER_SIGNAL)
        # white read noise of the light-sensitive pixels alone: sigma where they are, else 0
        self.white = (np.where(self.active, t.active_read_noise, 0.0).astype(engine.dtype)
                      if t.active_read_noise > 0 else None)
        self.white_rng = rng_for(engine.entropy, TIER_ACTIVE_WHITE)

    def _white_noise(self, scale=1.0):
        """A draw of the light-sensitive pixels' white read noise (times ``scale``)."""
        noise = self.white_rng.standard_normal(self.white.shape, dtype=self.white.dtype)
        noise *= self.white
        return noise * np.asarray(scale, dtype=noise.dtype) if scale != 1.0 else noise

    def _population(self, *key):
        """The generator of a pixel population: from the scene's ``population_seed`` (its
        own tier, apart from every noise stream) or, without one, the simulation's seed."""
        if self.t.population_seed is None:
            return rng_for(self.e.entropy, *key)
        return rng_for(self.t.population_seed, TIER_POPULATION, *key)

    def _poisson(self, mean):
        """Shot noise of charges ``mean`` (in the scene's unit)."""
        if self.shot == 1.0:
            return self.sig_rng.poisson(mean)
        return self.sig_rng.poisson(mean / self.shot) * self.shot

    @staticmethod
    def _rtn_step(pop, k):
        idx, rng, amp, p, state = pop
        if k > 0:
            state ^= rng.random(idx.size) < p
        return idx, amp * state

    def _telegraph_values(self, k):
        """``(index, values)`` of every telegraph population at frame ``k``."""
        for pop in self.rtn:
            yield self._rtn_step(pop, k)
        for ref in self.rtn_reference:
            yield ref.frame(k)

    def add_frame(self, k, frame, phantom):
        t0 = k * self.tframe
        if self.rate is not None:
            dt = self.tau if k == 0 else self.tframe
            mean = self.rate * dt
            inc = self._poisson(mean) if self.t.poisson else mean
            self.charge = inc if self.charge is None else self.charge + inc
            frame += self.charge.astype(frame.dtype)
        leak = self.t.leakage
        if leak:
            frame += (leak * (t0 + self.tau)).astype(frame.dtype)
            if phantom is not None:
                phantom += (leak * (t0 + self.tau_ph))[:, None]
        for idx, val in self._telegraph_values(k):
            frame.reshape(-1)[idx] += val.astype(frame.dtype)
        if self.white is not None:
            frame += self._white_noise()

    def add_slopes(self, data, phantom):
        w = self.e.frame_weights()
        n = w.size
        if self.rate is not None:
            data += self.rate.astype(data.dtype)
            if self.t.poisson:
                k = np.arange(n)
                var_unit = self.tframe * np.sum(w[:, None] * w[None, :] *
                                                np.minimum(k[:, None], k[None, :]))
                noise = self.sig_rng.standard_normal(data.shape)
                data += (noise * np.sqrt(self.rate * var_unit * self.shot)).astype(data.dtype)
        if self.white is not None:  # each frame's read weighed by the fit: sqrt(sum w^2)
            data += self._white_noise(float(np.sqrt(np.sum(w * w))))
        leak = self.t.leakage
        if leak:
            data += np.asarray(leak, dtype=data.dtype)
            if phantom is not None:
                phantom += leak
        npop = len(self.rtn) + len(self.rtn_reference)
        acc = [0.0] * npop
        index = [None] * npop
        for k in range(n):
            for j, (idx, val) in enumerate(self._telegraph_values(k)):
                acc[j] = acc[j] + w[k] * val
                index[j] = idx
        for idx, a in zip(index, acc, strict=True):
            data.reshape(-1)[idx] += np.asarray(a, dtype=data.dtype)


def simulate_to_fits(scene, path, *, mode=None, seed=None, overwrite=False, progress=False):
    """Simulate and write a FITS file; ramps are streamed frame by frame.

    Peak memory does not hold the cube: each frame is written as it is made
    by `~spherex_reduce.io.write_frames` (the file is the one
    `~spherex_reduce.io.write` gives for the simulated exposure), into a
    temporary file renamed into place when complete.  An existing ``path``
    is refused before anything is computed unless ``overwrite``.

    Returns
    -------
    path : `pathlib.Path`
    """
    atomic_output(path, overwrite)  # refuse before computing
    sc = load_scene(scene) if not hasattr(scene, "schedule") else scene
    if sc.synthesis.get("simulator", "spherex") != "spherex":  # a plugin's simulator
        return write(simulate(sc, mode=mode, seed=seed), path, overwrite=overwrite)
    sc, mode, seed, engine = _prepare(sc, mode, seed)
    if mode == "slopes":
        return write(_simulate(sc, mode=mode, seed=seed), path, overwrite=overwrite,
                     dtype=engine.dtype)
    s = sc.schedule
    frames = average_groups(_frames(sc, engine), s)
    frames = terminal_bar(progress, iterable=frames, total=s.nframes, unit="frame",
                          desc="simulate ramps")
    return write_frames(frames, path, s, header=_header(sc, mode, seed, engine), unit=sc.unit,
                        dtype=engine.dtype, overwrite=overwrite)
