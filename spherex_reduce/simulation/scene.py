"""The scene file (YAML or dict): validation with errors that name the YAML path."""

from dataclasses import asdict, dataclass, field, replace

from astropy import units as u

from ..core.errors import ConfigError
from ..core.limits import check_size
from ..core.parameters import Parameter, validate_parameters
from ..io.charge_unit import UNITS, scene_unit
from ..io.config import GEOMETRY_PARAMETERS, READOUT_PARAMETERS, load_yaml, schedule_from_config
from ..noise.section import section_components
from .synthesis import METHODS

__all__ = ["MODES", "UNITS", "Scene", "SceneTerms", "Telegraph", "load_scene", "scene_in_electrons",
           "scene_unit"]

MODES = ("slopes", "ramps")
_NUM = (int, float)
#: Largest current or telegraph step a scene accepts (e/s, e, Hz): far beyond any detector,
#: far below what overflows float32 or the Poisson generator.
MAX_RATE = 1e9
#: Longest low-frequency synthesis relative to the exposure.
MAX_PADDING = 1024
#: Most telegraph populations a scene's ``rtn:`` list may hold.
MAX_POPULATIONS = 16
SCENE_PARAMETERS = (
    Parameter("dark_current", 0.0, _NUM, "dark current of every active pixel (e/s)", minimum=0,
              maximum=MAX_RATE),
    Parameter("hot_pixel_fraction", 0.0, _NUM, "fraction of active pixels that are hot",
              minimum=0, maximum=1),
    Parameter("hot_pixel_current", 10.0, _NUM, "dark current of a hot pixel (e/s)", minimum=0,
              maximum=MAX_RATE),
    Parameter("photocurrent", 0.0, _NUM, "photocurrent of every active pixel (e/s)",
              minimum=0, maximum=MAX_RATE),
    Parameter("leakage", 0.0, _NUM, "Video8 leakage drift, seen by pixels and phantom (e/s)",
              minimum=-MAX_RATE, maximum=MAX_RATE),
    Parameter("poisson", True, (bool,), "Poisson noise on dark current and photocurrent"),
    Parameter("rtn", None, (dict, list, type(None)), "random telegraph noise: fraction, "
              "amplitude (e), rate (Hz), pixels (active, reference or all), or a list of such "
              "populations"),
    Parameter("dark_current_spread", 0.0, _NUM, "standard deviation of the active pixels' "
              "dark current (e/s; gamma-distributed about dark_current, which must be > 0)",
              minimum=0, maximum=MAX_RATE),
    Parameter("hot_pixel_current_spread", 0.0, _NUM, "standard deviation of the hot pixels' "
              "current (e/s; gamma-distributed about hot_pixel_current)", minimum=0,
              maximum=MAX_RATE),
    Parameter("active_read_noise", 0.0, _NUM, "white read noise of the light-sensitive "
              "pixels on top of the noise components' (standard deviation of one read, e): "
              "the reference pixels do not see it, so they read quieter, as NGHXRG's and "
              "JWST's do", minimum=0, maximum=MAX_RATE),
    Parameter("population_seed", None, (int, type(None)), "seed of the detector's pixel "
              "populations (which pixels are hot or telegraph, their currents, amplitudes and "
              "rates): the same for every simulation seed; null: drawn from the simulation's "
              "seed (each seed another detector)", minimum=0),
)
#: Which pixels ``scene.rtn`` puts telegraph noise in.
RTN_PIXELS = ("active", "reference", "all")
RTN_PARAMETERS = (
    Parameter("fraction", 0.0, _NUM, "fraction of the chosen pixels with telegraph noise",
              minimum=0, maximum=1),
    Parameter("amplitude", 0.0, _NUM, "step between the two states (e)", minimum=0,
              maximum=MAX_RATE),
    Parameter("rate", 0.1, _NUM, "switching rate of each state (Hz)", minimum=0,
              maximum=MAX_RATE),
    Parameter("amplitude_spread", 0.0, _NUM, "standard deviation of the pixels' steps (e; "
              "gamma-distributed about amplitude)", minimum=0, maximum=MAX_RATE),
    Parameter("rate_spread", 0.0, _NUM, "standard deviation of the pixels' rates (Hz; "
              "gamma-distributed about rate)", minimum=0, maximum=MAX_RATE),
    Parameter("pixels", "active", (str,), "active pixels, reference pixels (reference rows "
              "and side columns, seen at every read) or all", choices=RTN_PIXELS),
)
OUTPUT_PARAMETERS = (
    Parameter("mode", "slopes", (str,), "slopes or ramps", choices=MODES),
)
SYNTHESIS_PARAMETERS = (
    Parameter("method", "gaussian", (str,), "Fourier amplitudes: gaussian or random_phase "
              "(the paper's eq. 2-5)", choices=METHODS),
    Parameter("padding", None, (int, float, type(None)), "length of the low-frequency "
              "synthesis relative to the exposure (default 16; 1 for random_phase)", minimum=1,
              maximum=MAX_PADDING),
    Parameter("dtype", "float32", (str,), "dtype of the simulated arrays",
              choices=("float32", "float64")),
    Parameter("simulator", "spherex", (str,), "registered simulator that runs the scene"),
)
TOP_KEYS = ("geometry", "readout", "noise", "scene", "output", "synthesis", "seed", "unit",
            "gain")
#: The scene terms in the scene's unit (times the gain in electrons); the others are
#: fractions, rates in Hz or options.
CHARGE_TERMS = ("dark_current", "dark_current_spread", "hot_pixel_current",
                "hot_pixel_current_spread", "photocurrent", "leakage", "active_read_noise")
RTN_CHARGE_TERMS = ("amplitude", "amplitude_spread")


@dataclass(frozen=True)
class Telegraph:
    """Random telegraph noise of a scene (``scene.rtn``; see `RTN_PARAMETERS`).

    Attributes
    ----------
    fraction : float
        Fraction of the chosen pixels with telegraph noise.
    amplitude : float
        Step between the two states (e).
    rate : float
        Switching rate of each state (Hz).
    pixels : str
        ``active``, ``reference`` or ``all``.
    amplitude_spread, rate_spread : float
        Standard deviations of the pixels' amplitudes (e) and rates (Hz), each
        pixel's drawn from a gamma distribution of that mean and spread (0: all
        the same).
    """

    fraction: float
    amplitude: float
    rate: float
    pixels: str
    amplitude_spread: float = 0.0
    rate_spread: float = 0.0

    @property
    def on(self):
        """Whether it adds anything (a fraction of pixels and an amplitude above 0)."""
        return self.fraction > 0 and self.amplitude > 0


#: Largest spread**2 / mean (the scale of the gamma draw of a spread about a mean) a scene
#: takes: a spread of 1e9 about a mean of 1e-300 made the draws inf (and the ramps NaN).
MAX_GAMMA_SCALE = 1e30


def _check_spread(name, mean, spread):
    """Refuse a spread whose gamma draw about ``mean`` would not be finite."""
    if spread > 0 and mean > 0 and not spread * spread / mean <= MAX_GAMMA_SCALE:
        raise ConfigError(f"{name}: {spread:g} about a mean of {mean:g} is beyond what can "
                          f"be drawn (spread^2/mean above {MAX_GAMMA_SCALE:g})")


@dataclass(frozen=True)
class SceneTerms:
    """The ``scene:`` section of a scene: what is added to the readout's noise.

    The fields are `SCENE_PARAMETERS` (units there), ``rtn`` a `Telegraph`, a
    tuple of them (``rtn:`` a list of populations) or None; `telegraphs` is
    always the tuple.

    The pixel populations (which pixels are hot or telegraph, and each one's
    current, amplitude and rate) are drawn from ``population_seed`` when it is
    given, so that simulations with different seeds are darks of one detector
    (their noise differs); by default from the simulation's seed.

    Examples
    --------
    >>> from spherex_reduce.simulation import load_scene
    >>> t = load_scene({"scene": {"dark_current": 0.5, "rtn": {"fraction": 0.1}}}).terms
    >>> t.dark_current, t.rtn.fraction, t.rtn.pixels, t.rtn.on, t.population_seed
    (0.5, 0.1, 'active', False, None)
    >>> two = [{"fraction": 0.02, "amplitude": 30}, {"pixels": "reference", "amplitude": 9}]
    >>> [r.pixels for r in load_scene({"scene": {"rtn": two}}).terms.telegraphs]
    ['active', 'reference']
    """

    dark_current: float
    hot_pixel_fraction: float
    hot_pixel_current: float
    photocurrent: float
    leakage: float
    poisson: bool
    rtn: Telegraph | tuple | None
    dark_current_spread: float = 0.0
    hot_pixel_current_spread: float = 0.0
    active_read_noise: float = 0.0
    population_seed: int | None = None

    @classmethod
    def from_config(cls, section):
        """Validate a ``scene:`` mapping (None: the defaults); errors name ``scene.KEY``."""
        values = validate_parameters(section, SCENE_PARAMETERS, "scene")
        rtn = values["rtn"]
        if isinstance(rtn, dict):
            values["rtn"] = Telegraph(**validate_parameters(rtn, RTN_PARAMETERS, "scene.rtn"))
        elif isinstance(rtn, list):
            if not 1 <= len(rtn) <= MAX_POPULATIONS:
                raise ConfigError(f"scene.rtn: a list of 1 to {MAX_POPULATIONS} telegraph "
                                  f"populations, got {len(rtn)}")
            values["rtn"] = tuple(Telegraph(**validate_parameters(r, RTN_PARAMETERS,
                                                                  f"scene.rtn[{i}]"))
                                  for i, r in enumerate(rtn))
        if values["dark_current_spread"] > 0 and values["dark_current"] <= 0:
            raise ConfigError("scene.dark_current_spread: a spread about a dark_current of 0; "
                              "give dark_current > 0 or no spread")
        pairs = [("", values, "dark_current"), ("", values, "hot_pixel_current")]
        for i, t in enumerate(() if values["rtn"] is None else
                              (values["rtn"],) if isinstance(values["rtn"], Telegraph)
                              else values["rtn"]):
            where = "rtn." if isinstance(values["rtn"], Telegraph) else f"rtn[{i}]."
            pairs += [(where, vars(t), "amplitude"), (where, vars(t), "rate")]
        for where, v, name in pairs:
            _check_spread(f"scene.{where}{name}_spread", v[name], v[f"{name}_spread"])
        return cls(**values)

    @property
    def telegraphs(self):
        """The telegraph populations, a tuple of `Telegraph` (empty without ``rtn``)."""
        if self.rtn is None:
            return ()
        return (self.rtn,) if isinstance(self.rtn, Telegraph) else tuple(self.rtn)

    @property
    def currents(self):
        """Whether any pixel collects charge (dark current, photocurrent, hot pixels)."""
        return (self.dark_current > 0 or self.photocurrent > 0
                or (self.hot_pixel_fraction > 0 and self.hot_pixel_current > 0))

    def to_dict(self):
        """The terms as the validated mapping, in `SCENE_PARAMETERS` order."""
        return asdict(self)

    def scaled(self, gain):
        """These terms with every charge (currents, steps and their spreads) times ``gain``."""
        changes = {k: getattr(self, k) * gain for k in CHARGE_TERMS}
        pops = tuple(replace(r, **{k: getattr(r, k) * gain for k in RTN_CHARGE_TERMS})
                     for r in self.telegraphs)
        if pops:
            changes["rtn"] = pops[0] if isinstance(self.rtn, Telegraph) else pops
        return replace(self, **changes)


@dataclass(frozen=True)
class Scene:
    """A validated scene: schedule, noise components, scene terms and options.

    Build it with :func:`load_scene`.  ``unit`` is the unit of its charges
    (``unit:``, electrons by default, or adu with ``gain`` e-/adu): the noise
    coefficients are in ``unit²/Hz`` etc., the currents in ``unit/s``.
    """

    schedule: object
    components: tuple
    terms: SceneTerms
    mode: str = "slopes"
    seed: object = None
    synthesis: dict = field(default_factory=dict)
    source: str = "scene"
    config: dict = field(default_factory=dict)
    unit: object = u.electron
    gain: float | None = None

    def in_electrons(self, what="this"):
        """This scene with its charges in electrons (itself if they are).

        A scene in adu is converted with its ``gain``: noise coefficients times
        ``gain²``, currents and telegraph steps times ``gain``.

        Raises
        ------
        ConfigError
            In adu without a gain (``what`` names who needs electrons).

        Examples
        --------
        >>> from spherex_reduce.simulation import load_scene
        >>> sc = load_scene({"unit": "adu", "gain": 2.0, "scene": {"dark_current": 0.5},
        ...                  "noise": {"components": [{"name": "w", "alpha": 1e-3}]}})
        >>> e = sc.in_electrons()
        >>> str(e.unit), e.components[0].alpha, e.terms.dark_current
        ('electron', 0.004, 1.0)
        """
        if self.unit == u.electron:
            return self
        if self.gain is None:
            raise ConfigError(f"gain: {what} works in electrons and the scene ({self.source}) "
                              "is in adu without a gain: add gain: (e-/adu) to it")
        g = self.gain
        try:
            comps = tuple(c.replace(alpha=c.alpha * g * g, beta=c.beta * g * g,
                                    gamma=c.gamma * g * g) for c in self.components)
        except ValueError as exc:  # a coefficient times gain**2 beyond what a component takes
            raise ConfigError(f"gain: {g:g} e-/adu puts the scene's noise in electrons out "
                              f"of range: {exc}") from None
        return replace(self, components=comps, terms=self.terms.scaled(g), unit=u.electron,
                       gain=None, config=scene_in_electrons(self.config))

    def check_mode(self, mode):
        """Refuse to simulate this scene in ``mode`` if it cannot give a result.

        A slope needs at least two frames, and the simulation must fit in
        memory: one image (a frame, or the slopes), the low-frequency noise
        synthesised over ``padding`` times the exposure (at least one complex
        value per 32 row reads of every channel), and in ``ramps`` mode every
        sample of a frame of every channel.  This is a lower bound, made before
        anything is allocated, to refuse absurd scenes (``nframes: 1e12``) at
        once.

        Raises
        ------
        ConfigError
            ``mode`` unknown, or ``slopes`` with fewer than 2 frames or with
            groups of reads (simulated in ``ramps`` mode only: each group's
            simulated reads averaged, the reads between groups discarded).
        ResourceError
            The estimate exceeds what this machine can hold.
        """
        if mode not in MODES:
            raise ConfigError(f"output.mode: must be one of {list(MODES)}, got {mode!r}")
        s = self.schedule
        g = s.geometry
        if mode == "slopes" and s.nframes < 2:
            raise ConfigError(f"readout.nframes: a slope needs at least 2 frames, got "
                              f"{s.nframes} (use output.mode: ramps for one frame)")
        if mode == "slopes" and s.frames_read != s.nframes:
            raise ConfigError("output.mode: slopes are simulated for one read per frame; a "
                              "readout with groups or gaps needs output.mode: ramps")
        item = 8 if self.synthesis.get("dtype") == "float64" else 4
        padding = self.synthesis.get("padding")
        padding = 16.0 if padding is None else float(padding)
        exposure = float(s.frames_read) * float(s.frame_samples)  # samples per channel
        nbytes = padding * exposure / (32 * s.row_samples) * (g.nchannels + 1) * 16
        nbytes += float(s.n_reads) * g.ncols * (item if mode == "ramps" else 8)
        if mode == "ramps":
            nbytes += float(s.frame_samples) * g.nchannels * item
        check_size(nbytes, f"a {mode} simulation of {s.nframes} frames of {s.frame_samples} "
                   f"samples x {g.nchannels} channels, padding {padding:g}")


def load_scene(source=None):
    """Validate a scene (path, YAML text or dict; None = all defaults).

    Every key is optional; the defaults are the paper's Table 2/3 case.

    Raises
    ------
    ConfigError
        Unknown keys, wrong types, negative coefficients, unknown component
        names; the message names the YAML path (e.g. ``noise.components[2].beta``).

    Examples
    --------
    >>> from spherex_reduce.simulation import load_scene
    >>> sc = load_scene({"readout": {"nframes": 10}, "noise": {"components": ["roic"]}})
    >>> sc.schedule.nframes, [c.name for c in sc.components], sc.mode
    (10, ['roic'], 'slopes')
    >>> load_scene({"noise": {"components": [{"name": "x", "beta": -1}]}})
    Traceback (most recent call last):
    ...
    spherex_reduce.core.errors.ConfigError: noise.components[0].beta: must be >= 0, got -1.0
    """
    config, label = load_yaml({} if source is None else source, "scene")
    for key in config:
        if key not in TOP_KEYS:
            raise ConfigError(f"{label}: {key}: unknown section; valid: {', '.join(TOP_KEYS)}")
    unit, gain = scene_unit(config)
    validate_parameters(config.get("geometry"), GEOMETRY_PARAMETERS, "geometry")
    validate_parameters(config.get("readout"), READOUT_PARAMETERS, "readout")
    schedule = schedule_from_config(config.get("geometry"), config.get("readout"))
    components = section_components(config.get("noise"))
    terms = SceneTerms.from_config(config.get("scene"))
    output = validate_parameters(config.get("output"), OUTPUT_PARAMETERS, "output")
    synth = validate_parameters(config.get("synthesis"), SYNTHESIS_PARAMETERS, "synthesis")
    seed = config.get("seed")
    if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int) or seed < 0):
        raise ConfigError(f"seed: expected a non-negative integer or null, got {seed!r}")
    if (unit == u.adu and gain is None and terms.poisson and terms.currents):
        raise ConfigError("gain: a scene in adu with currents needs its gain (e-/adu) for "
                          "their shot noise; give gain:, or scene.poisson: false")
    scene = Scene(schedule, tuple(components), terms, output["mode"], seed, synth, label,
                  config, unit, gain)
    scene.check_mode(scene.mode)
    return scene


def scene_in_electrons(config, what="this"):
    """A scene mapping with its charges in electrons (`Scene.in_electrons`), as a mapping.

    A scene in electrons is returned as it is; one in adu with a gain gets
    its components (written out whole) ``alpha beta gamma`` times ``gain²`` and its scene
    terms' charges times ``gain`` (``unit`` and ``gain`` dropped).

    Raises
    ------
    ConfigError
        A bad ``unit`` or ``gain`` (`scene_unit`), or adu without a gain.

    Examples
    --------
    >>> from spherex_reduce.simulation.scene import scene_in_electrons
    >>> e = scene_in_electrons({"unit": "adu", "gain": 3, "scene": {"rtn": {"amplitude": 2}},
    ...                         "noise": {"components": [{"name": "w", "alpha": 1}]}})
    >>> e["scene"], e["noise"]["components"][0]["alpha"], "unit" in e
    ({'rtn': {'amplitude': 6.0}}, 9.0, False)
    """
    unit, gain = scene_unit(config)
    if unit == u.electron:
        return config
    if gain is None:
        raise ConfigError(f"gain: {what} works in electrons and the scene is in adu without a "
                          "gain: add gain: (e-/adu) to it")
    out = {k: v for k, v in config.items() if k not in ("unit", "gain")}
    comps = [c.replace(alpha=c.alpha * gain * gain, beta=c.beta * gain * gain,
                       gamma=c.gamma * gain * gain).to_dict()
             for c in section_components(config["noise"])]
    out["noise"] = {"components": comps}
    terms = config.get("scene")
    if isinstance(terms, dict):
        terms = dict(terms)
        for key in CHARGE_TERMS:
            if key in terms:
                terms[key] = _times(terms[key], gain, f"scene.{key}")
        rtn = terms.get("rtn")
        pops = [rtn] if isinstance(rtn, dict) else rtn if isinstance(rtn, list) else []
        pops = [{k: _times(v, gain, f"scene.rtn.{k}") if k in RTN_CHARGE_TERMS else v
                 for k, v in r.items()} if isinstance(r, dict) else r for r in pops]
        if pops:
            terms["rtn"] = pops[0] if isinstance(rtn, dict) else pops
        out["scene"] = terms
    return out


def _times(value, factor, path):
    if isinstance(value, str):
        try:
            value = float(value)
        except ValueError:
            pass
    if isinstance(value, bool) or not isinstance(value, _NUM):
        raise ConfigError(f"{path}: expected a number, got {value!r}")
    return float(value) * factor
