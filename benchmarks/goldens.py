"""Goldens for a restructuring: the reductions, the analysis tables and the public names, as hashes.

Reduces fixed-seed raw files with every shipped pipeline config, through every
route a user has (a path streamed by the executor, the exposure in memory, the
command line, one file per read, a 4-D file of integrations), and writes the
SHA-256 of every extension of every output (data, and header cards other than
checksums and dates; ``PROVENANCE`` without its ``elapsed`` column), with the
``__all__`` of every public module.  The analysis tables are hashed too, each
made by its command: ``forecast`` of a small scene through every pipeline it
takes, a forecast-only ``sweep --forecast``, ``design-readout`` (report and best
scene) and ``compare-strategies`` (their columns and meta, timings left out).
Run it before a change and after: the two JSON files must be identical.

    python benchmarks/goldens.py -o before.json
    ... change ...
    python benchmarks/goldens.py -o after.json --check before.json

The hashes depend on numpy, astropy and the platform: compare runs made in one
environment, not with another machine's file.
"""

import argparse
import hashlib
import importlib
import json
import re
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import yaml
from astropy.io import fits

#: not results: checksums, dates, and the config's hash (the config names temporary paths)
VOLATILE = {"CHECKSUM", "DATASUM", "DATE", "DATE-OBS", "DATE-END", "SXRCONF"}
PUBLIC_MODULES = [
    "spherex_reduce", "spherex_reduce.io", "spherex_reduce.reduce.steps", "spherex_reduce.noise",
    "spherex_reduce.simulation", "spherex_reduce.analysis", "spherex_reduce.plugin",
]
SCENE = {
    "geometry": {"nrows": 64, "ncols": 64, "nchannels": 4, "ref_border": 4},
    "readout": {"skip": 4, "ref_reads": 8, "ref_mode": "distributed", "phantom_reads": 2,
                "nframes": 6, "frame_overhead": 100},
    "noise": {"table": "spherex-table2"},
    "output": {"mode": "ramps"},
}


def _hash_hdu(hdu, work):
    h = hashlib.sha256()
    history = []
    for card in hdu.header.cards:
        if card.keyword in VOLATILE:
            continue
        value = str(card.value).replace(work, "WORK")  # input paths are recorded
        if card.keyword == "HISTORY":  # long texts wrap over cards: join them first
            history.append(value)
            continue
        h.update(f"{card.keyword}={value}\n".encode())
    # step timings ("unchop complete in 0.0003 s") are not results
    # (a card's trailing blank is lost where a wrap falls on it: compare without blanks)
    text = "".join("".join(history).split()).replace("".join(work.split()), "WORK")
    h.update(re.sub(r"in[0-9.e+-]+s:", "in?s:", text).encode())
    if hdu.data is not None:
        data = hdu.data
        if isinstance(hdu, (fits.BinTableHDU, fits.TableHDU)):
            for name in data.columns.names:
                if name == "elapsed":
                    continue
                h.update(name.encode())
                column = np.asarray(data[name])
                if column.dtype.kind in "SU":  # paths of inputs (e.g. PROVENANCE's inputs)
                    column = np.char.replace(column.astype(str), work, "WORK")
                h.update(np.ascontiguousarray(column).tobytes())
        else:
            h.update(np.ascontiguousarray(data).tobytes())
    return h.hexdigest()


def hash_file(path):
    """``{extension name: sha256}`` of a FITS file (the folder it is in named ``WORK``)."""
    out = {}
    with fits.open(path) as hdul:
        for i, hdu in enumerate(hdul):
            out[f"{i}:{hdu.name}"] = _hash_hdu(hdu, str(Path(path).parent))
    return out


def public_names():
    names = {}
    for module in PUBLIC_MODULES:
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        names[module] = sorted(getattr(mod, "__all__", []))
    return names


def make_inputs(work):
    from spherex_reduce.simulation import simulate_to_fits

    raw = work / "raw.fits"
    other = work / "other.fits"
    simulate_to_fits(SCENE, raw, seed=11)
    simulate_to_fits(SCENE, other, seed=12)
    # one file per read: a 2-D image each, the readout from the pipeline config
    reads = work / "reads"
    reads.mkdir()
    with fits.open(raw) as hdul:
        cube = hdul["SCI"].data
        for k in range(cube.shape[0]):
            fits.PrimaryHDU(cube[k]).writeto(reads / f"read_{k + 1:02d}.fits")
    readout = {**SCENE["readout"], "phantom_reads": 0}
    config = {"geometry": {**SCENE["geometry"], "pixel_rate": 1e5}, "readout": readout,
              "steps": ["unchop", "correct_reference", "fit_ramp", "sigma_clip"]}
    (work / "reads.yaml").write_text(yaml.safe_dump(config))
    # a 4-D file of two integrations
    four = work / "four.fits"
    with fits.open(raw) as hdul:
        copies = fits.HDUList([h.copy() for h in hdul])
        copies["SCI"].data = np.stack([hdul["SCI"].data, hdul["SCI"].data * 0.5 + 1])
        copies["PHANTOM"].data = np.stack([hdul["PHANTOM"].data, hdul["PHANTOM"].data])
        copies.writeto(four, checksum=True)
    return raw, other, reads, four


def run(work):
    import spherex_reduce as sr
    from spherex_reduce.io import write

    raw, other, reads, four = make_inputs(work)
    results = {"public_names": public_names()}
    configs = sorted(p.stem for p in
                     (Path(sr.__file__).parent / "data" / "configs").glob("*.yaml"))
    for name in configs:
        pipe = sr.Pipeline.from_yaml(name)
        config = pipe.config
        if name == "measured-dark-pair":
            for step in config["steps"]:
                if "pair_difference" in step:
                    step["pair_difference"]["other"] = str(other)
            pipe = sr.Pipeline(config, source=name)
        for route, source in (("path", str(raw)), ("memory", sr.read(raw))):
            out = work / f"{name}-{route}.fits"
            write(pipe.run(source, threads=2), out)
            results[f"{name}/{route}"] = hash_file(out)
    # the command line, streaming and whole
    for name in ("spherex-default", "wiener", "spherex-slopes"):
        out = work / f"{name}-cli.fits"
        subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "-q", "reduce", str(raw),
                        "-c", name, "-o", str(out)], check=True)
        results[f"{name}/cli"] = hash_file(out)
    out = work / "reads-cli.fits"
    subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "-q", "reduce", "--reads",
                    str(reads / "read_*.fits"), "-c", str(work / "reads.yaml"), "-o", str(out)],
                   check=True)
    results["spherex-default/reads-cli"] = hash_file(out)
    out = work / "four-cli.fits"
    subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "-q", "reduce", str(four),
                    "-c", "spherex-default", "-o", str(out)], check=True)
    results["spherex-default/4d-cli"] = hash_file(out)
    results.update(analysis_tables(work))
    return results


#: a small scene for the forecast, the sweep and the design (seconds, not minutes)
SMALL = {"geometry": {"nrows": 32, "ncols": 16, "nchannels": 2, "ref_border": 4},
         "readout": {"skip": 4, "ref_reads": 8, "phantom_reads": 2, "nframes": 4},
         "noise": {"table": "spherex-table2"}}
#: meta keys that are timings or paths, not results
TIMING_META = {"seconds", "elapsed", "time", "timings", "stage_seconds", "created"}


def _results_only(value):
    """``value`` (a table's meta) without its timings, at any depth, mappings sorted."""
    if isinstance(value, dict):
        return sorted(((str(k), _results_only(v)) for k, v in value.items()
                       if k not in TIMING_META and not str(k).endswith("seconds")), key=str)
    if isinstance(value, (list, tuple)):
        return [_results_only(v) for v in value]
    return value


def hash_table(path, work):
    """SHA-256 of an ECSV table's columns and meta (timings left out, ``work`` named ``WORK``)."""
    from astropy.table import Table

    table = Table.read(path, format="ascii.ecsv")
    h = hashlib.sha256()
    for name in table.colnames:
        if name in TIMING_META or name.endswith("_seconds"):
            continue
        h.update(name.encode())
        h.update(repr(table[name].tolist()).replace(str(work), "WORK").encode())
    text = repr(_results_only(dict(table.meta))).replace(str(work), "WORK")
    h.update(re.sub(r"[0-9.]+ s\b", "? s", text).encode())
    return h.hexdigest()


def _cli(*args):
    subprocess.run([sys.executable, "-m", "spherex_reduce.cli", "-q", *map(str, args)],
                   check=True)


def analysis_tables(work):
    out = {}
    scene = work / "small.yaml"
    scene.write_text(yaml.safe_dump(SMALL))
    for name in ("spherex-default", "spherex-slopes", "phantom-only", "acn", "wiener",
                 "unchop", "measured-dark-pair"):
        table = work / f"forecast-{name}.ecsv"
        _cli("forecast", scene, "-c", name, "-o", table, "--bins", 8, "--kmin", 0.2,
             "--kmax", 1.2)
        out[f"forecast/{name}"] = hash_table(table, work)
    sweep = work / "sweep.yaml"
    sweep.write_text(yaml.safe_dump({
        "scene": SMALL, "pipeline": ["spherex-default", "phantom-only"],
        "grid": {"skip": [1, 4], "ref_mode": ["repeated", "distributed"]},
        "realizations": 0, "measure": {"kmin": 0.2, "kmax": 1.2, "bins": 8}}))
    _cli("sweep", sweep, "-o", work / "sweep.ecsv", "--forecast", "--scheduler", "serial")
    out["sweep/forecast"] = hash_table(work / "sweep.ecsv", work)
    design = work / "design.yaml"
    design.write_text(yaml.safe_dump({
        "scene": SMALL, "band": {"kmin": 0.3, "kmax": 1.5}, "bins": 8,
        "baseline": {"skip": 4, "ref_reads": 8, "phantom_reads": 2},
        "search": {"skips": [1, 2, 3, 4], "phantom_reads": [0, 2], "ref_reads": [8, 12],
                   "iterations": 5},
        "realizations": 2}))
    _cli("design-readout", design, "-o", work / "best.yaml", "--report", work / "report.ecsv")
    out["design/report"] = hash_table(work / "report.ecsv", work)
    best = (work / "best.yaml").read_text().replace(str(work), "WORK")
    out["design/best"] = hashlib.sha256(best.encode()).hexdigest()
    compare = work / "compare.yaml"
    compare.write_text(yaml.safe_dump({
        "scene": {**SMALL, "geometry": {"nrows": 64, "ncols": 64, "nchannels": 4,
                                        "ref_border": 4}},
        "pipelines": ["spherex-default", "acn", "wiener"], "realizations": 2, "seed": 3}))
    _cli("compare-strategies", compare, "-o", work / "compare.ecsv", "--scheduler", "serial")
    out["compare/table"] = hash_table(work / "compare.ecsv", work)
    return out


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", required=True, help="JSON file to write")
    parser.add_argument("--check", help="an earlier JSON file that must be identical")
    args = parser.parse_args(argv)
    with tempfile.TemporaryDirectory() as tmp:
        results = run(Path(tmp))
    Path(args.output).write_text(json.dumps(results, indent=1, sort_keys=True))
    print(f"{len(results) - 1} outputs hashed into {args.output}")
    if args.check:
        before = json.loads(Path(args.check).read_text())
        differ = [key for key in sorted(set(before) | set(results))
                  if before.get(key) != results.get(key)]
        for key in differ:
            print(f"DIFFERS: {key}")
            b, a = before.get(key), results.get(key)
            if isinstance(b, dict) and isinstance(a, dict):
                for k in sorted(set(b) | set(a)):
                    if b.get(k) != a.get(k):
                        print(f"    {k}: {b.get(k)} -> {a.get(k)}")
        print("identical" if not differ else f"{len(differ)} differ")
        return 1 if differ else 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
