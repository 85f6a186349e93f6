"""The scene file (YAML or dict): validation with errors that name the YAML path."""

from dataclasses import asdict, dataclass, field

from ..core.errors import ConfigError
from ..core.limits import check_size
from ..core.parameters import Parameter, validate_parameters
from ..io.config import GEOMETRY_PARAMETERS, READOUT_PARAMETERS, load_yaml, schedule_from_config
from ..noise.section import section_components
from .synthesis import METHODS

__all__ = ["MODES", "Scene", "SceneTerms", "Telegraph", "load_scene"]

MODES = ("slopes", "ramps")
_NUM = (int, float)
#: Largest current or telegraph step a scene accepts (e/s, e, Hz): far beyond any detector,
#: far below what overflows float32 or the Poisson generator.
MAX_RATE = 1e9
#: Longest low-frequency synthesis relative to the exposure.
MAX_PADDING = 1024
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
    Parameter("rtn", None, (dict, type(None)), "random telegraph noise: fraction, amplitude "
              "(e), rate (Hz), pixels (active, reference or all)"),
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
TOP_KEYS = ("geometry", "readout", "noise", "scene", "output", "synthesis", "seed")


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
    """

    fraction: float
    amplitude: float
    rate: float
    pixels: str

    @property
    def on(self):
        """Whether it adds anything (a fraction of pixels and an amplitude above 0)."""
        return self.fraction > 0 and self.amplitude > 0


@dataclass(frozen=True)
class SceneTerms:
    """The ``scene:`` section of a scene: what is added to the readout's noise.

    The fields are `SCENE_PARAMETERS` (units there), ``rtn`` a `Telegraph` or None.

    Examples
    --------
    >>> from spherex_reduce.simulation import load_scene
    >>> t = load_scene({"scene": {"dark_current": 0.5, "rtn": {"fraction": 0.1}}}).terms
    >>> t.dark_current, t.rtn.fraction, t.rtn.pixels, t.rtn.on
    (0.5, 0.1, 'active', False)
    """

    dark_current: float
    hot_pixel_fraction: float
    hot_pixel_current: float
    photocurrent: float
    leakage: float
    poisson: bool
    rtn: Telegraph | None

    @classmethod
    def from_config(cls, section):
        """Validate a ``scene:`` mapping (None: the defaults); errors name ``scene.KEY``."""
        values = validate_parameters(section, SCENE_PARAMETERS, "scene")
        if values["rtn"] is not None:
            values["rtn"] = Telegraph(**validate_parameters(values["rtn"], RTN_PARAMETERS,
                                                            "scene.rtn"))
        return cls(**values)

    def to_dict(self):
        """The terms as the validated mapping, in `SCENE_PARAMETERS` order."""
        return asdict(self)


@dataclass(frozen=True)
class Scene:
    """A validated scene: schedule, noise components, scene terms and options.

    Build it with :func:`load_scene`.
    """

    schedule: object
    components: tuple
    terms: SceneTerms
    mode: str = "slopes"
    seed: object = None
    synthesis: dict = field(default_factory=dict)
    source: str = "scene"
    config: dict = field(default_factory=dict)

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
    scene = Scene(schedule, tuple(components), terms, output["mode"], seed, synth, label,
                  config)
    scene.check_mode(scene.mode)
    return scene
