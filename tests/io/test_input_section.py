"""The ``input:`` section of a pipeline config: unit, gain, dropped first reads, header policy.

Each file is built here from small arrays; slopes are checked against an
independent numpy least-squares fit of the values written, at the frames'
true times.
"""

import hashlib
import logging

import numpy as np
import pytest
from astropy import units as u
from astropy.io import fits

from spherex_reduce import DetectorGeometry, Pipeline, ReadoutSchedule, read
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, FormatError
from spherex_reduce.reduce.integrations import reduce_input

NFRAMES = 6
SCHEDULE = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=0), ref_mode="none",
                           phantom_reads=0, nframes=NFRAMES)
TIMES = np.arange(NFRAMES) * SCHEDULE.frame_time.to_value(u.s)  # true frame starts (s)


def adu_ramps(seed=1):
    """Integer ADU ramps (frames, 8, 8): a pedestal, a slope per pixel and noise."""
    rng = np.random.default_rng(seed)
    slope = rng.uniform(200, 2000, (8, 8))  # ADU/s
    values = 20000 + slope * TIMES[:, None, None] + rng.normal(0, 3, (NFRAMES, 8, 8))
    return np.round(values)


def write_file(path, values, dtype="uint16", bunit="ADU", drop_keys=(), **cards):
    header = SCHEDULE.to_header(fits.Header())
    for key in drop_keys:
        header.remove(key)
    if bunit is not None:
        header["BUNIT"] = bunit
    for key, value in cards.items():
        header[key] = value
    hdu = fits.PrimaryHDU(values.astype(np.float32), header=header)
    if dtype == "uint16":
        hdu.scale("int16", bzero=32768)  # how lab systems store raw ADU
    hdu.writeto(path)
    return path


def lstsq_slopes(values, times):
    """Least-squares slope (with an intercept) of every pixel of ``values`` (frames, r, c)."""
    design = np.stack([times, np.ones_like(times)], axis=1)
    coef, *_ = np.linalg.lstsq(design, values.reshape(len(times), -1).astype(float), rcond=None)
    return coef[0].reshape(values.shape[1:])


def digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def fit(input_section, **sections):
    return Pipeline({"input": input_section, **sections, "steps": ["fit_ramp"]})


def test_integer_adu_file_with_gain_gives_electrons(tmp_path):
    values = adu_ramps()
    path = write_file(tmp_path / "adu.fits", values)
    before = digest(path)
    out = fit({"unit": "adu", "gain": 2.0}).run(path)
    assert out.unit == u.electron / u.s
    assert out.header["GAIN"] == 2.0
    np.testing.assert_allclose(out.data.data, 2.0 * lstsq_slopes(values, TIMES), rtol=1e-5)
    assert digest(path) == before


def test_adu_spelling_without_input_section_is_adu(tmp_path):
    values = adu_ramps()
    path = write_file(tmp_path / "dn.fits", values, bunit="DN")
    out = Pipeline({"steps": ["fit_ramp"]}).run(path)
    assert out.unit == u.adu / u.s
    np.testing.assert_allclose(out.data.data, lstsq_slopes(values, TIMES), rtol=1e-5)


def test_unit_for_a_file_without_bunit(tmp_path):
    path = write_file(tmp_path / "nounit.fits", adu_ramps(), bunit=None)
    assert read(path).unit == u.electron  # as before: the default
    assert read(path, input={"unit": "counts"}).unit == u.adu


@pytest.mark.parametrize("dtype", ["float32", "uint16"])  # streamed in bands / read whole
def test_gain_per_channel_and_routes_agree(tmp_path, dtype):
    values = adu_ramps(2)
    path = write_file(tmp_path / "adu.fits", values, dtype=dtype)
    pipe = fit({"unit": "adu", "gain": [1.5, 3.0]})
    streamed = pipe.run(path)
    in_memory = pipe.run(pipe.read(path))
    np.testing.assert_array_equal(streamed.data.data, in_memory.data.data)
    gain = np.repeat([1.5, 3.0], 4)[None, :]  # 2 channels of 4 columns
    np.testing.assert_allclose(streamed.data.data, gain * lstsq_slopes(values, TIMES),
                               rtol=1e-5)
    assert (streamed.header["GAIN1"], streamed.header["GAIN2"]) == (1.5, 3.0)
    route = "a file" if dtype == "float32" else "memory"
    assert route in str(streamed.tables["PROVENANCE"]["route"][0])


@pytest.mark.parametrize("dtype", ["float32", "uint16"])
def test_drop_first_reads_fits_the_rest_at_their_true_times(tmp_path, dtype):
    values = adu_ramps(3)
    values[:2] += 500  # first reads off: a fit that used them would be far off
    path = write_file(tmp_path / "adu.fits", values, dtype=dtype)
    before = digest(path)
    pipe = fit({"unit": "adu", "drop_first_reads": 2})
    streamed = pipe.run(path)
    in_memory = pipe.run(pipe.read(path))
    np.testing.assert_array_equal(streamed.data.data, in_memory.data.data)
    np.testing.assert_allclose(streamed.data.data, lstsq_slopes(values[2:], TIMES[2:]),
                               rtol=1e-5)
    assert streamed.header["NDROPRD"] == 2
    assert streamed.header["NFRAMES"] == NFRAMES - 2
    assert digest(path) == before


def test_drop_first_reads_leaving_too_few_frames(tmp_path):
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    with pytest.raises(FormatError, match="at least 2 frames must remain"):
        read(path, input={"drop_first_reads": NFRAMES - 1})


def test_header_fill_refuses_a_disagreement(tmp_path):
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    pipe = fit({"unit": "adu"}, readout={"frame_time": 0.0376})
    with pytest.raises(FormatError) as exc:
        pipe.run(path)
    assert str(exc.value) == (
        f"{path}: keyword TFRAME is 0.0188 in the file but frame_time is 0.0376 in the config; "
        "fix the config, or set input.header: override to use the config's")


def test_header_fill_refusal_on_the_command_line(tmp_path, capsys):
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    cfg = tmp_path / "c.yaml"
    cfg.write_text("input: {unit: adu}\ngeometry: {nchannels: 4}\nsteps: [fit_ramp]\n")
    rc = main(["-q", "reduce", str(path), "-c", str(cfg), "-o", str(tmp_path / "o.fits")])
    err = capsys.readouterr().err.strip()
    assert rc == 2
    assert err.count("\n") == 0
    assert "keyword NCHAN is 2 in the file but nchannels is 4 in the config" in err
    assert not (tmp_path / "o.fits").exists()


def test_header_override_uses_the_config_with_a_warning(tmp_path, caplog):
    values = adu_ramps()
    # a foreign file: TFRAME (wrong) but no FRMOVH
    path = write_file(tmp_path / "adu.fits", values, dtype="float32", drop_keys=("FRMOVH",),
                      TFRAME=0.0376)
    pipe = fit({"unit": "adu", "header": "override"}, readout={"frame_time": 0.0188})
    with caplog.at_level(logging.WARNING):
        out = pipe.run(path)
    assert any("TFRAME = 0.0376 replaced by the config's 0.0188" in r.getMessage()
               for r in caplog.records)
    assert any("input.header override: TFRAME" in str(h) for h in out.header["HISTORY"])
    np.testing.assert_allclose(out.data.data, lstsq_slopes(values, TIMES), rtol=1e-5)
    assert out.header["TFRAME"] == 0.0188


def test_unit_disagreement_is_refused_unless_override(tmp_path):
    path = write_file(tmp_path / "e.fits", adu_ramps(), bunit="electron")
    with pytest.raises(FormatError, match="keyword BUNIT is 'electron' in the file but unit"):
        read(path, input={"unit": "adu"})
    assert read(path, input={"unit": "adu", "header": "override"}).unit == u.adu
    with pytest.raises(FormatError, match=r"input\.gain converts ADU to electrons"):
        read(path, input={"gain": 2.0})


def test_reduced_file_is_not_converted_twice(tmp_path):
    """A reduction written with GAIN and NDROPRD, read with the same config, stays as it is."""
    from spherex_reduce import write
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    pipe = fit({"unit": "adu", "gain": 2.0, "drop_first_reads": 1})
    out = write(pipe.run(path), tmp_path / "red.fits")
    again = pipe.read(out)
    np.testing.assert_array_equal(again.data.data, read(out).data.data)
    assert again.unit == u.electron / u.s


@pytest.mark.parametrize("section, message", [
    ({"gain": 0}, "input.gain: must be > 0, got 0.0"),
    ({"gain": -1.8}, "input.gain: must be > 0, got -1.8"),
    ({"gain": [1.0, -2]}, "input.gain[1]: must be > 0, got -2.0"),
    ({"gain": []}, "input.gain: expected a number or one number per channel, got an empty list"),
    ({"gain": "x"}, "input.gain: expected number or list or null, got 'x'"),
    ({"gian": 2}, "input.gian: unknown parameter; valid: unit, gain, drop_first_reads, header, "
                  "dq_bits"),
    ({"header": "merge"}, "input.header: 'merge' is not one of ['fill', 'override']"),
    ({"drop_first_reads": -1}, "input.drop_first_reads: must be >= 0, got -1"),
    ({"unit": "furlongs"}, "input.unit: 'furlongs' is not a unit astropy understands "
                           "(or ADU, DN, counts, ELECTRONS, e-)"),
    ({"dq_bits": -1}, "input.dq_bits: must be an integer from 0 to 4294967295"),
])
def test_bad_values_refused_in_one_line(section, message):
    with pytest.raises(ConfigError) as exc:
        fit(section)
    assert str(exc.value).startswith(message)
    assert "\n" not in str(exc.value)


def test_gain_count_must_match_the_channels(tmp_path):
    with pytest.raises(ConfigError, match=r"^input.gain: 3 values for 2 readout channels"):
        fit({"gain": [1, 2, 3]}, geometry={"nchannels": 2})
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    pipe = fit({"unit": "adu", "gain": [1, 2, 3]})  # the count is known from the file
    with pytest.raises(ConfigError, match=r"^input.gain: 3 values for 2 readout channels"):
        pipe.run(path)


def test_input_section_is_part_of_the_config_hash():
    plain = Pipeline({"steps": ["fit_ramp"]})
    assert "input" not in plain.config  # no section: the hash of existing configs is kept
    hashes = {fit(s).config_hash for s in ({}, {"gain": 2.0}, {"gain": 2.5},
                                            {"drop_first_reads": 1})}
    assert len(hashes) == 4
    assert fit({"gain": 2}).config["input"]["gain"] == 2.0


def test_dq_bits_from_the_input_section(tmp_path):
    values = adu_ramps()
    path = tmp_path / "dq.fits"
    header = SCHEDULE.to_header(fits.Header())
    dq = np.zeros((8, 8), np.int32)
    dq[1, 1] = 4  # bit 2: masks by default (every bit), not when dq_bits lacks it
    fits.HDUList([fits.PrimaryHDU(header=header),
                  fits.ImageHDU(values.astype(np.float32), name="SCI"),
                  fits.ImageHDU(dq, name="DQ")]).writeto(path)
    assert not read(path, input={"dq_bits": 1}).dq.any()
    assert read(path, input={"dq_bits": 4}).dq[:, 1, 1].all()
    assert read(path).dq[:, 1, 1].all()


def test_gain_scales_phantom_values_and_uncertainties(tmp_path):
    from spherex_reduce import Exposure, write
    s = ReadoutSchedule(DetectorGeometry(8, 8, 2, ref_border=0), ref_mode="none",
                        phantom_reads=2, nframes=4)
    rng = np.random.default_rng(5)
    data = rng.normal(1000, 5, (4, 8, 8)).astype(np.float32)
    phantom = rng.normal(900, 5, (4, 8, 2)).astype(np.float32)
    path = write(Exposure.from_arrays(data, s, unit=u.adu, phantom=phantom), tmp_path / "p.fits")
    gain = np.array([1.5, 3.0], np.float32)
    pipe = Pipeline({"input": {"gain": [1.5, 3.0]},
                     "steps": ["subtract_phantom", "fit_ramp"]})
    streamed = pipe.run(path)
    assert "a file" in str(streamed.tables["PROVENANCE"]["route"][0])
    by_hand = Exposure.from_arrays(data * np.repeat(gain, 4), s, unit=u.electron,
                                   phantom=phantom * gain)
    expected = Pipeline({"steps": ["subtract_phantom", "fit_ramp"]}).run(by_hand)
    np.testing.assert_array_equal(streamed.data.data, expected.data.data)
    image = write(Exposure.from_arrays(data[0], SCHEDULE, unit=u.adu / u.s,
                                       uncertainty=np.ones((8, 8), np.float32)),
                  tmp_path / "img.fits")
    e = read(image, input={"gain": [1.5, 3.0]})
    assert e.unit == u.electron / u.s
    np.testing.assert_array_equal(e.data.uncertainty.array, np.repeat(gain, 4)[None].repeat(8, 0))


def test_frame_time_against_a_file_with_frame_overhead_only(tmp_path):
    """The file states the frame time by FRMOVH: a config frame_time is checked against it."""
    values = adu_ramps()
    path = write_file(tmp_path / "adu.fits", values, dtype="float32", drop_keys=("TFRAME",))
    assert "FRMOVH" in fits.getheader(path)
    with pytest.raises(FormatError, match=r"keyword FRMOVH gives frame_time = 0\.0188 in the file "
                                          r"but frame_time is 0\.0376 in the config"):
        fit({}, readout={"frame_time": 0.0376}).run(path)
    fit({}, readout={"frame_time": 0.0188}).run(path)  # agrees: read
    out = fit({"header": "override"}, readout={"frame_time": 0.0376}).run(path)
    np.testing.assert_allclose(out.data.data, lstsq_slopes(values, 2 * TIMES), rtol=1e-5)


@pytest.mark.parametrize("dtype", ["float32", "uint16"])
def test_reads_as_files_with_gain_and_dropped_reads(tmp_path, dtype):
    """``reduce --reads``: the input: section applies to a ramp stored one file per read."""
    values = adu_ramps(7)
    values[:1] -= 300  # the first read off
    (tmp_path / "r").mkdir()
    header = SCHEDULE.to_header(fits.Header())
    header["BUNIT"] = "DN"
    for k in range(NFRAMES):
        hdu = fits.PrimaryHDU(values[k].astype(np.float32), header=header)
        if dtype == "uint16":
            hdu.scale("int16", bzero=32768)
        hdu.writeto(tmp_path / "r" / f"read_{k + 1}.fits")
    before = {p.name: digest(p) for p in (tmp_path / "r").iterdir()}
    cfg = tmp_path / "c.yaml"
    cfg.write_text("input: {gain: [2.0, 0.5], drop_first_reads: 1}\nsteps: [fit_ramp]\n")
    out = tmp_path / "o.fits"
    assert main(["-q", "reduce", "--reads", str(tmp_path / "r" / "read_*.fits"), "-c", str(cfg),
                 "-o", str(out)]) == 0
    gain = np.repeat([2.0, 0.5], 4)[None, :]
    with fits.open(out) as hdul:
        assert hdul[0].header["BUNIT"] == "electron / s" and hdul[0].header["NDROPRD"] == 1
        np.testing.assert_allclose(hdul["SCI"].data,
                                   gain * lstsq_slopes(values[1:], TIMES[1:]), rtol=1e-5)
    assert {p.name: digest(p) for p in (tmp_path / "r").iterdir()} == before


def test_unreadable_bunit_needs_override_to_be_replaced(tmp_path):
    path = write_file(tmp_path / "x.fits", adu_ramps(), bunit="bogons")
    with pytest.raises(FormatError, match=r"keyword BUNIT='bogons' is not a unit astropy "
                                          r"understands; set input\.unit to give the unit"):
        read(path)
    with pytest.raises(FormatError, match=r"set input\.header: override to give the unit"):
        read(path, input={"unit": "adu"})
    assert read(path, input={"unit": "adu", "header": "override"}).unit == u.adu


def test_drop_first_reads_of_an_image_is_refused(tmp_path):
    from spherex_reduce import Exposure, write
    path = write(Exposure.from_arrays(np.ones((8, 8), np.float32), SCHEDULE, unit=u.adu / u.s),
                 tmp_path / "img.fits")
    with pytest.raises(FormatError, match="holds an image, not ramps: there are no reads"):
        read(path, input={"drop_first_reads": 1})


def test_reduced_file_reads_again_with_the_config_that_gives_nframes(tmp_path):
    """``spectrum -c`` of a reduction made with ``drop_first_reads``: its NFRAMES counts the
    frames kept, the config's nframes the frames of the ramp; the two agree."""
    from spherex_reduce import write
    path = write_file(tmp_path / "adu.fits", adu_ramps())
    pipe = fit({"unit": "adu", "gain": 2.0, "drop_first_reads": 1}, readout={"nframes": NFRAMES})
    out = write(pipe.run(path), tmp_path / "red.fits")
    again = pipe.read(out)
    np.testing.assert_array_equal(again.data.data, read(out).data.data)
    with pytest.raises(FormatError, match=r"NFRAMES \(\+ NDROPRD 1 reads dropped\) is 5 in "
                                          "the file but nframes is 7"):
        fit({"unit": "adu"}, readout={"nframes": NFRAMES + 1}).read(out)


# Issue 31: the unit spellings of other systems, and one override warning per file


@pytest.mark.parametrize(("bunit", "unit"), [
    ("ELECTRONS", u.electron), ("electrons", u.electron), ("e-", u.electron),
    ("DN", u.adu), ("COUNTS", u.adu), ("counts", u.adu)])
def test_unit_spellings_of_other_systems(tmp_path, bunit, unit):
    """HST writes ELECTRONS and COUNTS, JWST DN, labs e-: understood as written, and a
    config stating the same unit agrees with them (no override needed)."""
    path = write_file(tmp_path / "u.fits", adu_ramps(), bunit=bunit)
    assert read(path).unit == unit
    assert read(path, input={"unit": unit.to_string()}).unit == unit


@pytest.mark.parametrize("bunit", ["DN/S", "ELECTRONS/S", "COUNTS/S"])
def test_per_second_is_seconds_not_siemens(bunit):
    from spherex_reduce.io.input import parse_unit
    assert parse_unit(bunit) * u.s in (u.adu, u.electron)


def test_override_warned_once_per_file_of_integrations(tmp_path, caplog):
    """A 4-D file read with header: override: one warning per keyword for the file, not one
    per integration."""
    values = np.stack([adu_ramps(1), adu_ramps(2), adu_ramps(3)]).astype(np.float32)
    header = SCHEDULE.to_header(fits.Header())
    header.remove("FRMOVH")
    header["TFRAME"], header["BUNIT"] = 0.0376, "ADU"
    path = tmp_path / "ints.fits"
    fits.HDUList([fits.PrimaryHDU(header=header), fits.ImageHDU(values, name="SCI")]
                 ).writeto(path)
    pipe = fit({"header": "override"}, readout={"frame_time": 0.0188})
    with caplog.at_level(logging.WARNING):
        _, images = reduce_input(path, pipe)
    notes = [r for r in caplog.records if "replaced by the config's 0.0188" in r.getMessage()]
    assert len(notes) == 1, [r.getMessage() for r in notes]
    np.testing.assert_allclose(images["INTSLOPE"][2].value, lstsq_slopes(values[2], TIMES),
                               rtol=1e-5)
