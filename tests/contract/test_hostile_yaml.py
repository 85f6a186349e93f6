"""Hostile YAML and hostile values: every command that reads YAML answers with one line, exit 2.

Each case is a file a careless or malicious user could pass: an alias bomb
("billion laughs"), a 5000-deep list, bytes that are not UTF-8, a FITS file,
duplicate keys, a file over the size limit, NaN and infinite numbers, sizes no
machine holds.  Nothing may be written, nothing may take more than a moment or
a bounded amount of memory.
"""

import json
import os
import subprocess
import sys
import textwrap

import numpy as np
import pytest

from spherex_reduce import DetectorGeometry, ReadoutSchedule
from spherex_reduce.cli import main
from spherex_reduce.core.errors import ConfigError, ResourceError
from spherex_reduce.io.config import MAX_YAML_BYTES, MAX_YAML_DEPTH, load_yaml, parse_yaml
from spherex_reduce.simulation import load_scene

SMALL_SCENE = {"geometry": {"nrows": 16, "ncols": 16, "nchannels": 2, "ref_border": 2},
               "readout": {"skip": 4, "ref_reads": 4, "nframes": 3, "phantom_reads": 2},
               "seed": 1}


def _bomb(levels=9, width=9, key="name"):
    """A "billion laughs" value of ``key``: ``width ** levels`` strings from a few hundred bytes."""
    items = [f"&a0 [{', '.join(['lol'] * width)}]"]
    items += [f"&a{i} [{', '.join([f'*a{i - 1}'] * width)}]" for i in range(1, levels + 1)]
    return f"{key}: [{', '.join(items)}]\n"


def _deep(depth=5000):
    return "steps: " + "[" * depth + "unchop" + "]" * depth + "\n"


HOSTILE = {
    "alias-bomb": lambda tmp: _bomb().encode(),
    "deep-list": lambda tmp: _deep().encode(),
    "not-utf8": lambda tmp: b"steps: [unchop]\nname: caf\xe9 \xff\xfe\n",
    "fits-file": lambda tmp: (b"SIMPLE  =                    T" + b" " * 49
                              + b"END" + b" " * 77) .ljust(2880, b" ") + b"\x00\xff" * 1440,
    "duplicate-key": lambda tmp: b"steps: [unchop]\nname: a\nname: b\n",
    "too-large": lambda tmp: b"name: " + b"x" * (MAX_YAML_BYTES + 10) + b"\nsteps: [unchop]\n",
    "recursive-alias": lambda tmp: b"steps: &s [unchop, *s]\n",
}
EXPECT = {
    "alias-bomb": "alias",
    "deep-list": f"deeper than {MAX_YAML_DEPTH}",
    "not-utf8": "not UTF-8 text",
    "fits-file": "FITS file",
    "duplicate-key": "key 'name' appears twice",
    "too-large": "1 MiB",
    "recursive-alias": "alias *s",
}


def _commands(path, out):
    """Every command line that reads the YAML file ``path``; ``out`` must not appear."""
    return {
        "show-config": ["show-config", str(path)],
        "reduce": ["reduce", str(out) + ".in.fits", "-c", str(path), "-o", str(out)],
        "simulate": ["simulate", str(path), "-o", str(out)],
        "sweep": ["sweep", str(path), "-o", str(out), "--scheduler", "serial"],
        "readout": ["readout", "--config", str(path), "-o", str(out)],
    }


def _one_line_error(capsys, code, *needles):
    err = capsys.readouterr().err
    assert code == 2, err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err and "unexpected failure" not in err
    for needle in needles:
        assert needle in lines[0], lines[0]
    return lines[0]


@pytest.mark.parametrize("command", ["show-config", "reduce", "simulate", "sweep", "readout"])
@pytest.mark.parametrize("kind", sorted(set(HOSTILE) - {"alias-bomb"}))
def test_hostile_yaml_one_line_exit_2(tmp_path, capsys, command, kind):
    path = tmp_path / "hostile.yaml"
    path.write_bytes(HOSTILE[kind](tmp_path))
    before = path.read_bytes()
    out = tmp_path / "out.fits"
    code = main(["-q", *_commands(path, out)[command]])
    _one_line_error(capsys, code, EXPECT[kind], str(path))
    assert not out.exists() and path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["hostile.yaml"]


def test_alias_bomb_is_refused_fast_in_bounded_memory(tmp_path):
    """Every command, in a child limited to 1 GiB of address space and 60 s.

    Before, ``show-config`` took > 4 GB and > 40 s on this file, and a bomb in
    ``description:`` 6.3 GB (the config hash expanded every alias).
    """
    paths = {}
    for key in ("name", "description"):
        paths[key] = tmp_path / f"bomb-{key}.yaml"
        paths[key].write_text(_bomb(key=key) + "steps: [unchop]\n")
    out = tmp_path / "out.fits"
    argvs = [argv for p in paths.values() for argv in _commands(p, out).values()]
    script = textwrap.dedent(f"""
        import io, json, resource, sys, time
        resource.setrlimit(resource.RLIMIT_AS, (1 << 30, 1 << 30))
        from spherex_reduce.cli import main
        results = []
        for argv in {json.dumps(argvs)}:
            sys.stderr = io.StringIO()
            t0 = time.perf_counter()
            code = main(["-q", *argv])
            results.append([code, time.perf_counter() - t0, sys.stderr.getvalue()])
        sys.stdout.write(json.dumps(results))
    """)
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1", OMP_NUM_THREADS="1", MKL_NUM_THREADS="1")
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                          timeout=60, env=env, check=False)
    assert proc.returncode == 0, proc.stderr[-2000:]
    results = json.loads(proc.stdout.strip().splitlines()[-1])
    assert len(results) == len(argvs)
    for argv, (code, seconds, err) in zip(argvs, results, strict=True):
        assert code == 2, (argv, err)
        assert len(err.strip().splitlines()) == 1 and "alias bomb" in err, (argv, err)
        assert seconds < 5, (argv, seconds)
    assert not out.exists()


# -- the loader itself ------------------------------------------------------------------
def test_small_anchors_and_merge_keys_still_work(tmp_path, capsys):
    text = textwrap.dedent("""
        steps:
          - sigma_clip: &clip {sigma: 3.0, maxiters: 5}
          - unchop
          - sigma_clip: {<<: *clip, sigma: 4.0}     # the same, but sigma 4
    """)  # the example of docs/yaml.rst
    data = parse_yaml(text)
    assert data["steps"][0] == {"sigma_clip": {"sigma": 3.0, "maxiters": 5}}
    assert data["steps"][2] == {"sigma_clip": {"sigma": 4.0, "maxiters": 5}}
    path = tmp_path / "p.yaml"
    path.write_text(text)
    assert main(["show-config", str(path)]) == 0
    assert "sigma: 4.0" in capsys.readouterr().out


def test_depth_limit_is_exact():
    def nested(depth):  # a mapping (1) holding a list nested depth - 2 times around a scalar
        return "k: " + "[" * (depth - 2) + "1" + "]" * (depth - 2)

    assert parse_yaml(nested(MAX_YAML_DEPTH)) is not None
    with pytest.raises(ConfigError, match=f"deeper than {MAX_YAML_DEPTH}"):
        parse_yaml(nested(MAX_YAML_DEPTH + 1))


def test_deep_through_aliases_is_refused():
    lines = ["a0: &a0 [1]"] + [f"a{i}: &a{i} [*a{i - 1}]" for i in range(1, 150)]
    with pytest.raises(ConfigError, match="through aliases"):
        parse_yaml("\n".join(lines))


def test_duplicate_keys_name_key_and_lines():
    with pytest.raises(ConfigError) as info:
        parse_yaml("readout:\n  skip: 8\n  nframes: 4\n  skip: 24\n", "x.yaml")
    assert str(info.value) == ("x.yaml: line 4: key 'skip' appears twice in one mapping "
                               "(first on line 2)")


def test_yaml_syntax_error_is_one_line():
    with pytest.raises(ConfigError) as info:
        parse_yaml("steps: [unchop\nname: x\n", "x.yaml")
    msg = str(info.value)
    assert "\n" not in msg and msg.startswith("x.yaml: not valid YAML:") and "line" in msg


def test_size_limit_applies_to_text_too():
    with pytest.raises(ConfigError, match="1 MiB"):
        load_yaml("name: " + "x" * MAX_YAML_BYTES + "\nsteps: [unchop]\n")


# -- values: finite, positive where zero is meaningless, bounded where they allocate ---------
@pytest.mark.parametrize(
    ("text", "needle"),
    [
        ("readout: {frame_time: .nan}\nsteps: [unchop]", "readout.frame_time: must be a finite"),
        ("readout: {frame_time: .inf}\nsteps: [unchop]", "readout.frame_time: must be a finite"),
        ("readout: {frame_time: 0}\nsteps: [unchop]", "readout.frame_time: must be > 0"),
        ("geometry: {pixel_rate: 0}\nsteps: [unchop]", "geometry.pixel_rate: must be > 0"),
        ("geometry: {pixel_rate: .nan}\nsteps: [unchop]", "geometry.pixel_rate: must be a finite"),
        ("steps: [sigma_clip: {sigma: .nan}]", "steps[0].sigma_clip.sigma: must be a finite"),
        ("steps: [sigma_clip: {sigma: 0}]", "steps[0].sigma_clip.sigma: must be > 0"),
        ("steps: [sigma_clip: {sigma_upper: -.inf}]", "sigma_upper: must be a finite"),
        ("steps: [fit_ramp: {gain: 0}]", "steps[0].fit_ramp.gain: must be > 0"),
        ("steps: [fit_ramp: {read_noise: .nan}]", "read_noise: must be a finite"),
        ("steps: [fit_ramp: {saturation: .inf}]", "saturation: must be a finite"),
        ("steps: [correct_reference: {strategy: mean, sigma: .nan}]", "sigma: must be a finite"),
    ],
)
def test_pipeline_values_nan_inf_zero(tmp_path, capsys, text, needle):
    path = tmp_path / "p.yaml"
    path.write_text(text + "\n")
    _one_line_error(capsys, main(["show-config", str(path)]), needle)


SCENE_CASES = [
    ({"scene": {"dark_current": float("nan")}}, "scene.dark_current: must be a finite"),
    ({"scene": {"photocurrent": float("inf")}}, "scene.photocurrent: must be a finite"),
    ({"scene": {"leakage": -1e300}}, "scene.leakage: must be in"),
    ({"scene": {"leakage": float("nan")}}, "scene.leakage: must be a finite"),
    ({"scene": {"hot_pixel_fraction": 1.5}}, "scene.hot_pixel_fraction: must be in [0, 1]"),
    ({"scene": {"rtn": {"fraction": 0.1, "amplitude": float("nan")}}}, "scene.rtn.amplitude"),
    ({"noise": {"components": [{"name": "w", "alpha": float("nan")}]}},
     "noise.components[0].alpha: must be a finite number >= 0"),
    ({"noise": {"components": [{"name": "w", "gamma": 1.0, "exponent": float("nan")}]}},
     "exponent must be in (0, 3)"),
    ({"readout": {"nframes": 1}}, "a slope needs at least 2 frames"),
    ({"readout": {"nframes": 10**12}}, "samples"),
    ({"readout": {"frame_time": 1e12}}, "frame_time"),
    ({"synthesis": {"padding": 1e12}}, "synthesis.padding: must be in [1, 1024]"),
    ({"geometry": {"nrows": 10**12, "ncols": 16, "nchannels": 2}}, "memory"),
]


@pytest.mark.parametrize(("change", "needle"), SCENE_CASES)
def test_scene_values_refused_before_simulating(tmp_path, capsys, change, needle):
    import yaml

    scene = {**SMALL_SCENE}
    for key, value in change.items():
        scene[key] = {**scene.get(key, {}), **value}
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    out = tmp_path / "out.fits"
    _one_line_error(capsys, main(["-q", "simulate", str(path), "-o", str(out)]), needle)
    assert not out.exists()


def test_one_frame_slopes_refused_also_when_mode_given_on_the_command_line(tmp_path, capsys):
    import yaml

    scene = {**SMALL_SCENE, "readout": {**SMALL_SCENE["readout"], "nframes": 1},
             "output": {"mode": "ramps"}}
    path = tmp_path / "scene.yaml"
    path.write_text(yaml.safe_dump(scene))
    out = tmp_path / "out.fits"
    assert main(["-q", "simulate", str(path), "-o", str(out)]) == 0  # one frame of ramps: fine
    out.unlink()
    _one_line_error(capsys, main(["-q", "simulate", str(path), "-o", str(out), "--mode",
                                  "slopes"]), "at least 2 frames")
    assert not out.exists()


def test_small_scene_still_simulates_and_is_finite():
    from spherex_reduce import simulate

    image = simulate({**SMALL_SCENE, "scene": {"leakage": -5.0, "dark_current": 1.0}})
    assert image.shape == (16, 16) and np.isfinite(image.data).all()


@pytest.mark.parametrize(
    ("sweep", "needle"),
    [
        ("realizations: 100000000000", "realizations must be a whole number from 1 to"),
        ("realizations: 100\ngrid: {skip: [1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15, "
         "16, 17, 18, 19, 20, 21, 22, 23, 24, 25, 26, 27, 28, 29, 30, 31, 32, 33, 34, 35, 36, "
         "37, 38, 39, 40, 41, 42, 43, 44, 45, 46, 47, 48, 49, 50], ref_reads: [0, 2, 4, 6, "
         "8, 10, 12, 14, 16, 18, 20, 22, 24, 26, 28, 30, 32, 34, 36, 38, 40]}",
         "number of cells"),
        ("scene: {scene: {photocurrent: .nan}}", "scene: scene.photocurrent: must be a finite"),
        ("scene: {readout: {frame_time: 1.0e+12}}", "frame_time"),
    ],
)
def test_sweep_refused_before_scheduling(tmp_path, capsys, sweep, needle):
    path = tmp_path / "sweep.yaml"
    path.write_text(sweep + "\n")
    out = tmp_path / "r.ecsv"
    code = main(["-q", "sweep", str(path), "-o", str(out), "--scheduler", "serial"])
    _one_line_error(capsys, code, needle)
    assert not out.exists()


@pytest.mark.parametrize(("flag", "value"), [("--frame-time", "nan"), ("--frame-time", "inf"),
                                             ("--pixel-rate", "nan"), ("--pixel-rate", "0"),
                                             ("--nrows", "300000000000")])
def test_readout_numbers(capsys, flag, value):
    _one_line_error(capsys, main(["readout", flag, value]), flag)


def test_load_scene_api_refuses_nan_too():
    with pytest.raises(ConfigError, match="finite"):
        load_scene({"scene": {"photocurrent": float("nan")}})
    with pytest.raises(ResourceError):
        load_scene({"readout": {"nframes": 10**9}})


def test_schedule_api_refuses_nan_and_absurd_sizes():
    with pytest.raises(ValueError, match="pixel_rate"):
        DetectorGeometry(pixel_rate=float("nan"))
    with pytest.raises(ValueError, match="pixel_rate"):
        DetectorGeometry(pixel_rate="1e5")
    with pytest.raises(ValueError, match="frame_time"):
        ReadoutSchedule(frame_time=True)
    with pytest.raises(ValueError, match="frame_time"):
        ReadoutSchedule(frame_time=1e12)
    with pytest.raises(ValueError, match="nframes"):
        ReadoutSchedule(nframes=10**15)
    with pytest.raises(ResourceError, match="row reads"):
        ReadoutSchedule(DetectorGeometry(nrows=10**13, ncols=64, nchannels=1))
    with pytest.raises(ResourceError, match="channels"):
        DetectorGeometry(ncols=2**50, nchannels=2**50)


# -- noise tables: coefficients finite, >= 0 and bounded; exponent in (0, 3) ----------------
def _table_with(column, value):
    import importlib.resources

    from astropy.table import Table

    path = importlib.resources.files("spherex_reduce") / "data" / "spherex-table2.ecsv"
    with importlib.resources.as_file(path) as p:
        table = Table.read(p, format="ascii.ecsv")
    table[column][0] = value
    return table


@pytest.mark.parametrize(
    ("column", "value", "needle"),
    [("alpha", np.nan, "alpha must be >= 0"), ("beta", np.inf, "beta must be >= 0"),
     ("gamma", 1e300, "gamma must be >= 0 and <= 1e+12"), ("alpha", -1e300, "alpha must be"),
     ("exponent", np.nan, "exponent must be in (0, 3)"),
     ("exponent", np.inf, "exponent must be in (0, 3)"),
     ("exponent", 0.0, "exponent must be in (0, 3)"),
     ("exponent", 1.0, "exponent must be in (0, 3)")],
)
def test_noise_table_values(tmp_path, capsys, column, value, needle):
    table_path = tmp_path / "table.ecsv"
    _table_with(column, value).write(table_path, format="ascii.ecsv")
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"noise: {{table: {table_path}}}\n")
    out = tmp_path / "out.fits"
    line = _one_line_error(capsys, main(["-q", "simulate", str(scene), "-o", str(out)]), needle)
    assert "noise.table[0] (video8)" in line and not out.exists()


@pytest.mark.parametrize("content", [b"not a table\n", b"\x00\xff" * 100,
                                     b"# %ECSV 1.0\n" + b"#" * (2 << 20)])
def test_noise_table_not_a_table(tmp_path, capsys, content):
    table_path = tmp_path / "table.ecsv"
    table_path.write_bytes(content)
    scene = tmp_path / "scene.yaml"
    scene.write_text(f"noise: {{table: {table_path}}}\n")
    code = main(["-q", "simulate", str(scene), "-o", str(tmp_path / "out.fits")])
    _one_line_error(capsys, code, "noise.table:", str(table_path))


def test_optimal_weighting_with_zero_read_noise(tmp_path, capsys):
    """Was a singular covariance matrix: exit 1, 'unexpected failure: LinAlgError'."""
    import yaml

    raw = tmp_path / "raw.fits"
    scene = tmp_path / "scene.yaml"
    scene.write_text(yaml.safe_dump({**SMALL_SCENE, "output": {"mode": "ramps"},
                                     "scene": {"photocurrent": 1.0}}))
    assert main(["-q", "simulate", str(scene), "-o", str(raw)]) == 0
    config = tmp_path / "p.yaml"
    config.write_text("steps:\n  - fit_ramp: {weighting: optimal, read_noise: 0}\n")
    out = tmp_path / "red.fits"
    capsys.readouterr()
    code = main(["-q", "reduce", str(raw), "-c", str(config), "-o", str(out)])
    _one_line_error(capsys, code, "read_noise > 0")
    assert not out.exists()


@pytest.mark.parametrize("step", ["sigma_clip: {maxiters: 1000000000000}",
                                  "correct_reference: {strategy: mean, maxiters: 1000000000000}"])
def test_iteration_counts_are_bounded(tmp_path, capsys, step):
    """Was exit 1 at run time: 'OverflowError: Python integer ... out of bounds for int32'."""
    path = tmp_path / "p.yaml"
    path.write_text(f"steps:\n  - {step}\n")
    _one_line_error(capsys, main(["show-config", str(path)]), "maxiters: must be in [1, 1000]")
