"""What a user sees of the commands: their output, help texts, listings and the plots they save.

Labels carry the real unit, the sweep plot drawn in memory is the plot of the
written table, and demo and spectrum give one band power for one file.
"""

import pytest
from _figure_checks import saved_figures
from astropy import units as u
from astropy.table import Table

from spherex_reduce.cli import main

SWEEP = {
    "scene": {"geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
              "readout": {"nframes": 4, "phantom_reads": 2, "ref_reads": 8}},
    "grid": {"skip": [1, 4], "ref_mode": ["repeated", "distributed"]},
    "realizations": 1,
    "seed": 3,
    "measure": {"kmin": 0.1, "kmax": 1.0, "bins": 6},
}


def _lines(fig):
    """``(label, x, y)`` of every error-bar series of the first axes."""
    ax = fig.axes[0]
    return sorted((c.get_label(), tuple(c.lines[0].get_xdata()), tuple(c.lines[0].get_ydata()))
                  for c in ax.containers)


# -- sweep --plot -------------------------------------------------------------------------
def test_sweep_plot_in_memory_equals_plot_of_the_file(tmp_path, monkeypatch):
    """The in-memory results carry the grid, so ``--plot`` draws against the first key."""
    import yaml

    import spherex_reduce.io.plotting as plotting
    from spherex_reduce.analysis.sweep import plot_sweep

    drawn = []
    real_save = plotting.save_figure
    monkeypatch.setattr(plotting, "save_figure",
                        lambda fig, *a, **k: (drawn.append(fig), real_save(fig, *a, **k))[1])
    path = tmp_path / "sweep.yaml"
    path.write_text(yaml.safe_dump(SWEEP, sort_keys=False))
    out = tmp_path / "res.ecsv"
    assert main(["-q", "sweep", str(path), "-o", str(out), "--scheduler", "serial",
                 "--plot"]) == 0
    (fig,) = drawn
    assert fig.axes[0].get_xlabel() == "skip"
    from_file = plot_sweep(Table.read(out))
    assert _lines(fig) == _lines(from_file)
    unit = Table.read(out)["band_power"].unit
    assert fig.axes[0].get_ylabel() == f"band power ({unit.to_string('latex_inline')})"
    # one line per ref_mode, two points (skip 1, 4) each
    assert [(lab, x) for lab, x, _ in _lines(fig)] == [
        ("ref_mode=distributed", (1, 4)), ("ref_mode=repeated", (1, 4))]


# -- one band power -----------------------------------------------------------------------
@pytest.fixture(scope="module")
def demo_dir(tmp_path_factory):
    """A small demo run: its directory and its figures by file name."""
    import spherex_reduce.analysis.figures.demo as demo

    out = tmp_path_factory.mktemp("demo")
    figs = saved_figures(demo, ["-q", "demo", "--size", "256", "--nframes", "3", "-o", str(out),
                                        "--keep-raw"])
    return out, figs


def test_demo_and_spectrum_give_one_band_power(demo_dir, tmp_path):
    """The same file, the same band: the same number from ``demo`` and ``spectrum``.

    256² is the smallest size at which the binned P(k) that demo used straddles the band.
    """
    demo_dir, _ = demo_dir
    demo_meta = Table.read(demo_dir / "spectra.ecsv").meta
    for label in ("chopped", "unchopped"):
        out = tmp_path / f"{label}.ecsv"
        assert main(["spectrum", str(demo_dir / f"reduced_{label}.fits"), "-o", str(out)]) == 0
        spec = Table.read(out).meta
        assert demo_meta["band_power_unit"] == spec["band_power_unit"]
        for name in ("band_power", "band_power_err"):  # demo measures before the file
            # rounds its image to float32 (3e-9 of the band power at 256^2)
            assert demo_meta[f"{name}_{label}"] == pytest.approx(spec[name], rel=1e-7)


def test_demo_table_stores_numbers_in_the_unit_of_its_columns(demo_dir):
    """The band powers were strings with units ('16258.87 electron2 pix2 / s2') where
    spectrum and forecast write a number and band_power_unit."""
    from astropy.table import QTable

    demo_dir, _ = demo_dir
    table = QTable.read(demo_dir / "spectra.ecsv")
    unit = u.Unit(table.meta["band_power_unit"])
    assert unit == table["power_chopped"].unit == table["power_unchopped"].unit
    assert unit == u.electron**2 / u.s**2 * u.pix**2
    for key in ("band_power_chopped", "band_power_err_chopped", "band_power_unchopped",
                "band_power_err_unchopped", "photon_noise_power"):
        assert type(table.meta[key]) is float and table.meta[key] > 0, key


# -- help texts and listings -------------------------------------------------------------
def _help(command):
    """``spherex-reduce COMMAND --help`` as printed, and the help of each of its arguments
    (the text after the option's column, lines joined, up to the next argument)."""
    import contextlib
    import io
    import re

    out = io.StringIO()
    with contextlib.redirect_stdout(out), pytest.raises(SystemExit):
        main([command, "--help"])
    text = out.getvalue()
    entries = re.split(r"\n  (?=[-\w])", text.split("\npositional arguments:", 1)[-1])
    described = {}
    for entry in entries[1:]:
        head, _, rest = entry.partition("  ")
        described[head.split(",")[0].split()[0]] = " ".join(rest.split())
    return text, described


@pytest.mark.parametrize("command", ["reduce", "combine"])
def test_every_argument_of_reduce_and_combine_is_described(command):
    """reduce --help showed IN.fits, -c and -o with no word on what they are."""
    _, described = _help(command)
    assert {"-c", "-o", "IN.fits"} & set(described)
    assert not [name for name, text in described.items() if not text], described


def test_reduce_help_names_the_shipped_configs():
    from pathlib import Path

    import spherex_reduce

    _, described = _help("reduce")
    shipped = sorted(p.stem for p in (Path(spherex_reduce.__file__).parent / "data"
                                      / "configs").glob("*.yaml"))
    assert len(shipped) >= 5
    assert all(name in described["-c"] for name in shipped), described["-c"]
    assert "a directory" in described["-o"] and "exists" in described["-o"]
    assert "raw FITS file" in described["IN.fits"]


def test_readout_help_says_each_choice_once_and_lists_the_presets():
    """--channels said 'columns, rows or quadrants: columns, rows, quadrants'; --preset did
    not say which presets there are."""
    _, described = _help("readout")
    for flag, words in {"--channels": ("columns", "rows", "quadrants"),
                        "--first-corner": ("outer", "inner"),
                        "--fast-axis": ("rows", "columns"),
                        "--ref-mode": ("none", "repeated", "distributed")}.items():
        text = described[flag].split("(default:")[0]
        assert all(text.count(word) == 1 for word in words), (flag, text)
    # the presets of docs/measured_darks.rst
    presets = ("H2RG", "H4RG-10", "WFC3-IR", "SIDECAR", "SIDECAR-science")
    assert all(name in described["--preset"] for name in presets), described["--preset"]


def test_readout_help_describes_every_option_with_its_default(capsys):
    from spherex_reduce.cli.readout import OPTIONS
    from spherex_reduce.io.config import (
        GEOMETRY_PARAMETERS,
        READOUT_PARAMETERS,
        WINDOW_PARAMETERS,
    )

    with pytest.raises(SystemExit):
        main(["readout", "--help"])
    text = " ".join(capsys.readouterr().out.split())  # unwrap argparse's lines
    declared = {p.name: p for p in (*GEOMETRY_PARAMETERS, *READOUT_PARAMETERS,
                                    *WINDOW_PARAMETERS)}
    assert len(OPTIONS) == 30  # one per field (4 of them the channel layout and preset)
    for flag, _, key, _ in OPTIONS:
        p = declared[key]
        after = text.split(f"{flag} {key.upper()} ", 1)[1]
        assert after.startswith(p.doc), flag
        if p.default is not None:
            default = f"{p.default:g}" if isinstance(p.default, float) else str(p.default)
            assert after.split("(default: ", 1)[1].startswith(default + ")"), flag
        else:
            assert "(default: " in after.split(" --", 1)[0], flag
    assert "(default: 1816, the paper's 1.51 s frame" in text
    assert "as text: the path of an ECSV file of one integer column, in read order (default: " \
        "from --skip, --ref-reads and --ref-mode)" in text
    assert "--first-row FIRST_ROW window: its first row in the full array (default: no " \
        "window)" in text
    assert "--groups GROUPS reads (0-based frames) averaged into each group, instead of " \
        "frames_per_group, as text: 0;1-2;3-6 (';' between groups, a-b a run of reads)" in text
    assert "--read-times READ_TIMES time (s) of every stored frame's read, for reads at " \
        "uneven times, as text: 0,2.93,12.93 (s, ',' between reads)" in text


def test_show_config_list_gives_each_shipped_config_its_description(capsys):
    import importlib.resources

    import yaml

    assert main(["show-config", "--list"]) == 0
    lines = capsys.readouterr().out.splitlines()
    configs = importlib.resources.files("spherex_reduce") / "data" / "configs"
    shipped = sorted(p.name[:-5] for p in configs.iterdir() if p.name.endswith(".yaml"))
    assert [line.split()[0] for line in lines] == shipped
    for name, line in zip(shipped, lines, strict=True):
        description = yaml.safe_load((configs / f"{name}.yaml").read_text())["description"]
        assert 10 < len(description) < 62 and "\n" not in description
        assert line.split(None, 1)[1] == description
        assert line.index(description) == lines[0].index(lines[0].split(None, 1)[1])


def test_plugins_names_distribution_and_version_in_aligned_columns(capsys):
    import importlib.metadata

    import spherex_reduce

    assert main(["plugins"]) == 0
    lines = capsys.readouterr().out.splitlines()
    header = lines[0]
    assert header.split() == ["kind", "name", "keyword", "strategies", "plugin", "distribution"]
    starts = [header.index(w) for w in header.split()]
    rows = [line for line in lines[1:] if not line.startswith("blocked")]
    for line in rows:
        for s in starts[1:]:  # every column starts where its heading does
            assert line[s - 2:s] == "  " or len(line) <= s, line
        assert line[starts[4]] != " " and line[starts[5]] != " ", line
    by_name = {line.split()[1]: line for line in rows}
    own = f"spherex-reduce {spherex_reduce.__version__}"
    assert by_name["correct_reference"].endswith(own)
    assert "S_REFCOR" in by_name["correct_reference"]
    assert by_name["unchop"][starts[4]:].split()[0] == "builtin.unchop"
    for ep in importlib.metadata.entry_points(group="spherex_reduce"):
        installed = f"{ep.dist.name} {ep.dist.version}"  # e.g. spherex-reduce-destripe 0.1.0
        assert any(line.endswith(installed) and f" {ep.name} " in line for line in rows)


def test_counts_of_one_are_singular(capsys):
    from spherex_reduce import DetectorGeometry, ReadoutSchedule

    summary = ReadoutSchedule(DetectorGeometry(64, 64, 1, ref_border=4)).summary()
    assert "1 channel of 64 columns" in summary
    assert "2 channels of 32 columns" in ReadoutSchedule(DetectorGeometry(64, 64, 2,
                                                                          ref_border=4)).summary()
    assert main(["readout", "--nrows", "64", "--ncols", "64", "--nchannels", "1"]) == 0
    out = capsys.readouterr().out
    assert "1 channel of" in out and "channels" not in out


def test_demo_spectra_legend_and_unit(demo_dir):
    """The photon line says its flux and time; the P(k) unit is LaTeX, not 'electron2'."""
    from spherex_reduce.io import read

    out, figs = demo_dir
    ax = figs["spectra.png"].axes[0]
    assert ax.get_ylabel() == "P(k) ($\\mathrm{electron^{2}\\,pix^{2}\\,s^{-2}}$)"
    schedule = read(out / "raw_chopped.fits").schedule
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    (photon,) = [t for t in legend if t.startswith("photon noise")]
    assert "1 e/s" in photon
    assert f"{schedule.integration_time.to_value(u.s):.3g} s" in photon
    assert f"N = {schedule.nframes}" in photon


def test_fit_noise_plot_names_streams_and_unit(demo_dir, tmp_path, monkeypatch):
    import spherex_reduce.io.plotting as plotting
    from spherex_reduce.io import read

    out, _ = demo_dir
    figs = []
    real_save = plotting.save_figure  # still written: the outputs are renamed together
    monkeypatch.setattr(plotting, "save_figure",
                        lambda fig, *a, **k: (figs.append(fig), real_save(fig, *a, **k))[1])
    raw = out / "raw_chopped.fits"
    assert main(["-q", "fit-noise", str(raw), "-o", str(tmp_path / "fit.ecsv"), "--plot",
                 str(tmp_path / "fit.png")]) == 0
    (ax,) = figs[0].axes
    unit = read(raw).unit**2 / u.Hz
    assert ax.get_ylabel() == f"one-sided PSD ({unit.to_string('latex_inline')})"
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert not any("spectrum" in t for t in legend)
    assert {"reference: border columns", "reference: re-read rows", "phantom"} <= set(legend)
