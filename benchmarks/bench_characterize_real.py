"""``characterize`` on real darks: the three PRIME H4RG-10 reads.

Run: ``python benchmarks/bench_characterize_real.py [--prime DIR] [--cache DIR]
[--pixel-rate HZ] [--frame-time S] [--gain E_PER_ADU]``.

PRIME (the PRime-focus Infrared Microlensing Experiment) published three reads of
one dark of its H4RG-10 with its up-the-ramp code: ``tests/input/DarkN{1,2,3}-0.fit.ref``
of ``github.com/IonaKondo/Sampling_up_the_ramp_20220519`` at commit
``2d9b78f3040dbe352a0fe0ca19cf9745d370ef54`` (deleted from that repository's head
later).  The script downloads them from raw.githubusercontent.com into ``--cache``
(outside this repository; their bytes are checked against the SHA-256 below), or
takes the directory ``--prime`` holding them.  Nothing of theirs is in this
repository: that repository states no licence.

What the files are, measured here: one primary HDU each, float32 whole numbers of
ADU, ``(4096, 128)``: one 128-column output (the first of the array's 32) of the
4096² array, one read per file, already reference-corrected (``.ref``: their code
subtracts the median of the top 4 rows of each output from each read).  The header
says nothing else: no date, detector, exposure time, frame time, pixel rate or
gain, and the repository does not give them either (its up-the-ramp code takes
3 reads and its own fixed gain constant, 1 or 2 e/ADU in its two programs).  The
config the script writes therefore *states* what is unknown:
``geometry: {preset: H4RG-10, nrows: 4096, ncols: 128, pixel_rate}``, ``window:
{first_row: 0, first_column: 0}`` (the preset is the full array: the window's
reference border, top and bottom rows and the left columns, is derived) and
``readout: {nframes: 3, frame_time, ...}``; ``frame_time`` is required for a
window and must be at least the time to read the window's 4096 rows of 128 pixels
at ``pixel_rate``.  ``--pixel-rate`` (default 100 kHz) and ``--frame-time``
(default that minimum) are assumptions, printed as such.  ``--gain``, if given,
goes to ``input: gain``.

It then runs ``spherex-reduce characterize --reads 'DIR/DarkN*-0.fit.ref'`` (the
three files are the reads of one dark) and, to show what a user who gives them as
darks sees, ``spherex-reduce characterize DIR/DarkN1-0.fit.ref ...``, and prints
each command's exit status and what it wrote: either the model's lines, or the
one-line refusal naming the term and the reason.  For context it prints what numpy
finds in the files (not a result of ``characterize``), and what
`~spherex_reduce.analysis.pixel_terms.fit_pixel_terms` gives from this one dark
alone (its errors come from groups of pixels; it needs ``--gain`` for ADU darks).
"""

import argparse
import hashlib
import os
import subprocess
import sys
import tempfile
import urllib.request
from pathlib import Path

import numpy as np
import yaml
from astropy.io import fits

COMMIT = "2d9b78f3040dbe352a0fe0ca19cf9745d370ef54"
URL = ("https://raw.githubusercontent.com/IonaKondo/Sampling_up_the_ramp_20220519/"
       f"{COMMIT}/tests/input/{{name}}")
FILES = {"DarkN1-0.fit.ref": "cbbebafd3eea2c0818e9fce76562d4d1a3c84d0a98d46b970a29667b2434739c",
         "DarkN2-0.fit.ref": "90c3cf3ccf3322891a3875fc3b10c7ebd0a2b6245a2ed68150a251ddd14a4fa3",
         "DarkN3-0.fit.ref": "da39dd911cc3283208fe975a46f9a40d8ee9ce2ba7e89d3ad3f14a64d31d0b80"}
NROWS, NCOLS, BORDER = 4096, 128, 4


def sha256(path):
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def fetch(cache):
    """The three files in ``cache``, downloaded at the pinned commit when missing."""
    cache.mkdir(parents=True, exist_ok=True)
    for name, digest in FILES.items():
        path = cache / name
        if not path.exists() or sha256(path) != digest:
            print(f"downloading {URL.format(name=name)}")
            try:
                with urllib.request.urlopen(URL.format(name=name), timeout=60) as r:
                    data = r.read(8 << 20)
            except OSError as exc:  # URLError, timeouts
                sys.exit(f"cannot download {name}: {exc}; give --prime DIR holding the files")
            tmp = path.with_suffix(".part")
            tmp.write_bytes(data)
            tmp.replace(path)
    return cache


def check(folder):
    """The three files of ``folder``, each checked against its pinned SHA-256."""
    paths = [folder / name for name in FILES]
    for path, digest in zip(paths, FILES.values(), strict=True):
        if not path.exists():
            sys.exit(f"{path}: missing (give --prime DIR holding {', '.join(FILES)})")
        if sha256(path) != digest:
            sys.exit(f"{path}: not the file of commit {COMMIT[:7]} (SHA-256 differs)")
    return paths


def facts(paths):
    """What numpy finds in the reads (context: not a result of characterize)."""
    reads = []
    for p in paths:
        with fits.open(p) as hdul:
            if len(hdul) != 1:
                sys.exit(f"{p}: {len(hdul)} HDUs, expected one")
            reads.append(np.asarray(hdul[0].data, dtype=np.float64))
            dtype = hdul[0].data.dtype
    x = np.stack(reads)
    light = x[:, BORDER:-BORDER, BORDER:]

    def robust_sd(a):
        return 1.4826 * float(np.median(np.abs(a - np.median(a))))

    d01, d12 = light[1] - light[0], light[2] - light[1]
    second = light[0] - 2 * light[1] + light[2]
    rows = [("shape, type", f"{x.shape[1:]} {dtype}, whole numbers: "
             f"{bool(np.all(x == np.rint(x)))}"),
            ("median of the top 4 rows (ADU)", f"{np.median(x[:, :BORDER]):.1f}"),
            ("median of the bottom 4 rows (ADU)", f"{np.median(x[:, -BORDER:]):.1f}"),
            ("median of the left 4 columns (ADU)",
             f"{np.median(x[:, BORDER:-BORDER, :BORDER]):.1f}"),
            ("median of the light-sensitive pixels (ADU)", f"{np.median(light):.1f}"),
            ("robust sd of read 1 - read 0, read 2 - read 1 (ADU)",
             f"{robust_sd(d01):.2f}, {robust_sd(d12):.2f}"),
            ("robust sd of the differences / sqrt 2 (ADU, per read)",
             f"{robust_sd(np.concatenate([d01.ravel(), d12.ravel()])) / np.sqrt(2):.2f}"),
            ("robust sd of x0 - 2 x1 + x2 / sqrt 6 (ADU, after a line per pixel)",
             f"{robust_sd(second) / np.sqrt(6):.2f}")]
    return rows


def config(pixel_rate, frame_time, gain):
    inp = {"unit": "adu"}
    if gain is not None:
        inp["gain"] = gain
    return {"input": inp,
            "geometry": {"preset": "H4RG-10", "nrows": NROWS, "ncols": NCOLS,
                         "pixel_rate": pixel_rate},
            "window": {"first_row": 0, "first_column": 0},
            "readout": {"skip": 1, "ref_reads": 0, "ref_mode": "none", "phantom_reads": 0,
                        "row_overhead": 0, "nframes": len(FILES), "frame_time": frame_time},
            "steps": [{"fit_ramp": {}}]}


def characterize(args, work):
    """``spherex-reduce characterize ARGS`` in a fresh process: exit status and its lines."""
    cmd = [sys.executable, "-m", "spherex_reduce.cli", "characterize", *args]
    env = {**os.environ, "OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS", "1")}
    r = subprocess.run(cmd, capture_output=True, text=True, cwd=work, env=env, timeout=600)
    lines = [ln for ln in (r.stdout + r.stderr).splitlines() if ln.strip()]
    return r.returncode, lines


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--prime", type=Path, help="a directory holding the three files")
    ap.add_argument("--cache", type=Path,
                    default=Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache"))
                    / "spherex_reduce" / "prime",
                    help="where to download them (default ~/.cache/spherex_reduce/prime)")
    ap.add_argument("--pixel-rate", type=float, default=1.0e5,
                    help="Hz per output (not in the files: assumed 100 kHz)")
    ap.add_argument("--frame-time", type=float, default=None,
                    help="s (not in the files: assumed the time to read 4096 rows of 128 "
                    "pixels at --pixel-rate)")
    ap.add_argument("--gain", type=float, default=None,
                    help="e/ADU for input: gain (not in the files: default none)")
    args = ap.parse_args()
    folder = args.prime if args.prime is not None else fetch(args.cache)
    paths = check(folder)
    frame_time = args.frame_time or NROWS * NCOLS / args.pixel_rate

    print(f"PRIME reads (commit {COMMIT[:7]}): {folder}")
    print("\n| what the files hold (numpy) | value |\n|---|---|")
    for what, value in facts(paths):
        print(f"| {what} | {value} |")
    print(f"\nassumed (the files and their repository do not say): pixel_rate "
          f"{args.pixel_rate:g} Hz, frame_time {frame_time:g} s"
          + ("" if args.gain is None else f", gain {args.gain:g} e/ADU") + "; stated: "
          "unit adu, one 128-column output at the array's corner (window of H4RG-10), "
          "3 reads, no phantom samples, no extra reference-row reads (the border's "
          "reference pixels are in the window)")

    with tempfile.TemporaryDirectory(prefix="prime-") as work:
        cfg = Path(work) / "prime.yaml"
        cfg.write_text(yaml.safe_dump(config(args.pixel_rate, frame_time, args.gain),
                                      sort_keys=False))
        print("\nprime.yaml:\n" + "\n".join("    " + ln for ln in cfg.read_text().splitlines()))
        glob = str(folder / "DarkN*-0.fit.ref")
        runs = [("one dark, a file per read", ["--reads", glob]),
                ("the reads given as darks", [str(p) for p in paths])]
        print("\n| input | command | exit | output |\n|---|---|---|---|")
        for what, inputs in runs:
            status, lines = characterize([*inputs, "-c", str(cfg), "-o", "model.yaml",
                                          "--report", "model.ecsv"], work)
            shown = ("spherex-reduce characterize --reads 'DIR/DarkN*-0.fit.ref'"
                     if inputs[0] == "--reads" else
                     "spherex-reduce characterize DIR/DarkN1-0.fit.ref ... DarkN3-0.fit.ref")
            text = "<br>".join(ln.replace("|", "\\|") for ln in lines)
            print(f"| {what} | `{shown} -c prime.yaml -o model.yaml` | {status} | {text} |")
            if status == 0:
                print("\n".join(Path(work, "model.yaml").read_text().splitlines()[:40]))
    pixel_terms(paths, frame_time, args.gain)


def pixel_terms(paths, frame_time, gain):
    """The per-pixel terms of the one dark alone (`fit_pixel_terms`: errors from groups of
    pixels, not from a scatter between darks), or its one-line refusal."""
    from astropy import units as u

    from spherex_reduce.analysis.pixel_terms import fit_pixel_terms
    from spherex_reduce.core.errors import SpherexReduceError

    x = u.Quantity(np.stack([fits.getdata(p).astype(np.float32) for p in paths]), u.adu)
    ref = np.zeros((NROWS, NCOLS), bool)
    ref[:BORDER] = ref[-BORDER:] = True
    ref[:, :BORDER] = True
    print("\nper-pixel terms of the one dark (spherex_reduce.analysis.pixel_terms."
          "fit_pixel_terms, errors from 32 groups of pixels):")
    try:
        res = fit_pixel_terms(x, np.arange(len(paths)) * frame_time * u.s, reference=ref,
                              gain=gain)
    except SpherexReduceError as exc:
        print(f"    refused: {exc}")
        return
    print("\n| term | pixels | value | error | unit | status |\n|---|---|---|---|---|---|")
    for r in res.table:
        if r["status"] != "not constrained":
            print(f"| {r['term']} | {r['pixels']} | {r['value']:.4g} | {r['error']:.2g} | "
                  f"{r['unit']} | {r['status']} |")
    nc = sorted({r["term"] for r in res.table if r["status"] == "not constrained"})
    print(f"\nnot constrained: {', '.join(nc)}")


if __name__ == "__main__":
    main()
