"""characterize on darks shaped like NGHXRG's (the JWST noise generator): per-pixel white
noise, lower on the reference pixels; a 1/f stream common to all outputs (its ``c_pink``);
one per output (``u_pink``); alternating column noise, independent even and odd streams
(``acn``).  Drawn here sample by sample (`_darks.dark`), not with NGHXRG
(``benchmarks/bench_characterize_nghxrg.py`` runs NGHXRG itself)."""

import numpy as np
import pytest
from _darks import dark, schedule

from spherex_reduce.analysis.characterize import characterize
from spherex_reduce.analysis.characterize.model import goodness
from spherex_reduce.analysis.characterize.spectra import band_power
from spherex_reduce.simulation import load_scene, simulate

FS = 1e5
#: white per pixel sample: reference pixels (sigma 4) and light-sensitive ones (sigma 5)
REF, LIGHT = 2 * 4.0**2 / FS, 2 * 5.0**2 / FS
#: 1/f levels (unit^2) of the common stream, each output's, and each ACN parity stream's
C_PINK, U_PINK, ACN = 0.6, 0.2, 0.3
BAND = (20.0, 300.0)  # within the spectra the darks give (row reads at 735 Hz)


def nghxrg_like(components, n=6, seed=0):
    """Darks of 128-column outputs (reference-row bursts of 64 samples per parity), the
    light-sensitive pixels given their extra white noise on top of the reference level."""
    s = schedule(nrows=64, ncols=512, nchannels=4, nframes=5, phantom_reads=0)
    light = ~s.geometry.reference_pixel_mask()[s.rows]
    out = []
    for k in range(n):
        d = dark(s, [{"name": "white", "alpha": REF}, *components], 100 * seed + k)
        data = np.array(d.data.data)
        extra = np.random.default_rng(10_000 + 100 * seed + k).normal(
            0, np.sqrt((LIGHT - REF) * FS / 2), data.shape)
        data[:, light] += extra[:, light]
        out.append(d.replace(data=type(d.data)(data)))
    return out


def band(est, exponent):
    """An estimate's 1/f band power in `BAND` and its jackknife error."""
    value = band_power(est.values[1], est.values[2], exponent, BAND)
    jack = np.array([band_power(b, g, exponent, BAND) for _, b, g in est.leave_one_out])
    k = jack.size
    return value, np.sqrt((k - 1) / k * np.sum((jack - jack.mean()) ** 2))


def test_reference_white_level_is_not_raised_by_the_common_one_over_f():
    """NGHXRG's common 1/f is as strong as the reference pixels' white noise at ~2 kHz, in
    the reference-row bursts' band: the bursts' white level is the reference pixels' own
    (2 sigma^2 / fs), not raised by the 1/f (it was, by 14 %, when the bursts were fitted
    with a white level alone)."""
    model = characterize(nghxrg_like([{"name": "c", "beta": C_PINK, "scope": "common"}]),
                         segments=1, pixels=False)
    ref = model.spectra["reference"]
    assert ref.values[0] == pytest.approx(REF, abs=4 * ref.errors[0])
    assert ref.values[0] == pytest.approx(REF, rel=0.05)
    assert not any("visibly bad" in m for m in model.marks), model.marks


def test_the_model_holds_the_reference_and_the_light_sensitive_white_levels_apart():
    """Reference pixels quieter than the light-sensitive ones (sigma 4 and 5 per sample):
    the model's components hold the reference level, ``scene.active_read_noise`` the
    light-sensitive pixels' excess (3 per read), each within its errors, and a simulation
    of the model reads both: its reference and light-sensitive pixels' reads differ by the
    darks' variances (16 and 25) within 5 % and 10 % (the light-sensitive level's fit
    has an error of 7 %)."""
    model = characterize(nghxrg_like([], n=16, seed=1), segments=1)
    ref, pix = model.spectra["reference"], model.spectra["pixels"]
    sc = load_scene(model.scene())
    held = sum(c.alpha for c in sc.components if c.seen_by_pixels)
    assert held == pytest.approx(REF, abs=3 * ref.errors[0])
    excess = 2 * sc.terms.active_read_noise**2 / FS  # as a white level
    assert excess == pytest.approx(LIGHT - REF, abs=3 * np.hypot(ref.errors[0], pix.errors[0]))
    assert any(m.startswith("reference:") and "holds both" in m for m in model.marks)
    e = simulate(dict(model.scene(), output={"mode": "ramps"}), seed=0)
    d = np.diff(np.asarray(e.data.data, dtype=np.float64), axis=0) / np.sqrt(2)
    mask = np.asarray(e.reference_pixel_mask())
    assert d[:, mask].var() == pytest.approx(REF * FS / 2, rel=0.05)
    assert d[:, ~mask].var() == pytest.approx(LIGHT * FS / 2, rel=0.1)  # (fit: 7 %)


def test_the_common_white_level_comes_from_the_reference_bursts_under_a_strong_common_drift():
    """NGHXRG's common 1/f drowns the white level of the light-sensitive streams' cross-
    spectrum (row means: before, ``common.alpha`` came out ± 9e-4 about a white level of
    5e-4, and with it each pixel's white level): the reference-row bursts of the outputs,
    read at the same times at the pixel rate, give it (0 here, none of the white noise is
    common) to a few 1e-6, and with it the scene's two white levels, each within 3 of its
    errors."""
    model = characterize(nghxrg_like([{"name": "c", "beta": C_PINK, "scope": "common"}],
                                     n=16, seed=1), segments=1)
    common = model.components["common"]
    assert abs(common.values[0]) < 3 * common.errors[0] < 0.05 * REF
    _, light_err, _, ref_err = model._white_levels(model.faint_white())
    sc = load_scene(model.scene())
    held = sum(c.alpha for c in sc.components if c.seen_by_pixels)
    assert held == pytest.approx(REF, abs=3 * ref_err)
    assert held + 2 * sc.terms.active_read_noise**2 / FS == pytest.approx(LIGHT,
                                                                         abs=3 * light_err)
    assert any(m.startswith("reference:") and "holds both" in m for m in model.marks)


def test_the_common_reference_spectrums_fit_is_judged_with_its_own_scatter():
    """The bursts' mean cross-spectrum over channel pairs scatters less than one channel's
    spectrum (its pairs of independent channels average: 1/(C − 1) of the variance for
    white noise): its chi2 over 3 sets of darks is ~1 per degree of freedom when judged
    with that scatter (it came out ~1/3: a bad fit could not be called so)."""
    per_dof = []
    for seed in (1, 2, 3):
        model = characterize(nghxrg_like([], n=16, seed=seed), segments=1)
        chi2, dof, _ = goodness(model.bins, 4)["reference_common"]
        per_dof.append(chi2 / dof)
    assert 0.7 < np.mean(per_dof) < 2.5, per_dof


def test_acn_is_a_component_of_its_own_beside_each_outputs_one_over_f():
    """Each output's own 1/f (one stream for both parities) and ACN (one per parity) come
    back apart: the channel component is the output's 1/f, the acn component ACN's (when
    ACN was put on the channel component the channel held 2 u_pink + acn)."""
    comps = [{"name": "c", "beta": C_PINK, "scope": "common"},
             {"name": "u", "beta": U_PINK, "scope": "channel"},
             {"name": "a", "beta": ACN, "scope": "channel", "acn": True}]
    model = characterize(nghxrg_like(comps, n=8, seed=1), segments=1, pixels=False)
    assert model.acn["found"]
    e = model.exponent
    lnb = np.log(BAND[1] / BAND[0])
    for name, level in (("channel", U_PINK), ("acn", ACN), ("common", C_PINK)):
        value, err = band(model.components[name], e)
        assert value == pytest.approx(level * lnb, abs=4 * err), name
        assert value == pytest.approx(level * lnb, rel=0.15), name
    scene = {c["name"]: c for c in model.scene()["noise"]["components"]}
    assert scene["acn"]["acn"] is True and scene["channel"]["acn"] is False


def test_a_right_fit_of_outputs_sharing_a_stream_is_not_called_bad():
    """Outputs that share one 1/f stream move together, so the channels' mean spectrum
    scatters as if from fewer streams: the goodness of fit allows for it, and the fit of
    the right model passes (the fits' own chi2 takes the four channels as independent)."""
    model = characterize(nghxrg_like([{"name": "c", "beta": 3 * C_PINK, "scope": "common"}],
                                     n=8, seed=2), segments=1, pixels=False)
    fits = goodness(model.bins, 4)
    for name in ("pixels", "pixels_common"):
        chi2, dof, p = fits[name]
        assert p > 1e-6, (name, chi2, dof)
    assert not any("visibly bad" in m for m in model.marks), model.marks


def test_a_line_the_model_lacks_is_called_bad():
    """A sinusoid in every output (a spectral line no term of the model has) is marked."""
    ds = nghxrg_like([], n=6, seed=3)
    out = []
    for d in ds:
        s = d.schedule
        t = (np.arange(s.nframes)[:, None, None] * s.frame_samples + s.pixel_samples()) / FS
        data = np.array(d.data.data) + 3.0 * np.sin(2 * np.pi * 97.0 * t)
        out.append(d.replace(data=type(d.data)(data)))
    model = characterize(out, segments=1, pixels=False)
    assert any(m.startswith("pixels: the fit is visibly bad") for m in model.marks)


def test_acn_is_not_found_where_the_darks_scatter_less_than_their_noise():
    """The jackknife sees only the scatter between darks: the same dark given three times
    has none, and every power was then 'found' (z infinite).  The error is floored at the
    fit's own, so the even-odd difference of noise without ACN is not taken for ACN."""
    (d,) = nghxrg_like([{"name": "u", "beta": U_PINK, "scope": "channel"}], n=1, seed=6)
    model = characterize([d, d, d], segments=1, pixels=False)
    assert model.acn["power"] > 0  # this seed: the case the jackknife's zero error hid
    assert np.isfinite(model.acn["z"]) and not model.acn["found"]
