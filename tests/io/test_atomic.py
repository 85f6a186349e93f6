"""`atomic_output` never replaces a file that takes the output's name while it is written."""

import errno
import os

import pytest

from spherex_reduce.io import atomic_output


def test_a_file_that_appears_while_writing_is_kept(tmp_path):
    out = tmp_path / "x.txt"
    with pytest.raises(FileExistsError, match="appeared while writing"), \
            atomic_output(out) as tmp:
        tmp.write_text("mine")
        out.write_text("another process's")
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"]
    assert out.read_text() == "another process's"


def test_without_hard_links_the_output_is_renamed(tmp_path, monkeypatch):
    def no_links(src, dst):
        raise OSError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(os, "link", no_links)
    out = tmp_path / "x.txt"
    with atomic_output(out) as tmp:
        tmp.write_text("mine")
    assert [p.name for p in tmp_path.iterdir()] == ["x.txt"] and out.read_text() == "mine"
    out.unlink()
    with pytest.raises(FileExistsError), atomic_output(out) as tmp:
        tmp.write_text("again")
        out.write_text("theirs")
    assert out.read_text() == "theirs"


def test_an_existing_output_is_refused_in_astropys_words(tmp_path, monkeypatch):
    """``sr.write`` onto an existing file (the README's snippet after its commands) stopped
    on a FileExistsError an astropy user does not expect: the words are astropy's own (an
    OSError), with the option of the command line."""
    import numpy as np
    from astropy.io import fits

    from spherex_reduce import DetectorGeometry, Exposure, ReadoutSchedule, write

    monkeypatch.chdir(tmp_path)
    s = ReadoutSchedule(DetectorGeometry(4, 4, 1, ref_border=0), ref_mode="none",
                        phantom_reads=0, nframes=2)
    e = Exposure.from_arrays(np.ones((4, 4)), s, order="physical")
    write(e, "reduced.fits")
    before = (tmp_path / "reduced.fits").read_bytes()
    with pytest.raises(OSError) as ours:
        write(e, "reduced.fits")
    with pytest.raises(OSError) as astropys:
        fits.writeto("reduced.fits", np.zeros(2))
    assert str(ours.value).startswith(str(astropys.value).rstrip(".")), (ours, astropys)
    assert str(ours.value).endswith("(on the command line: --overwrite).")
    assert (tmp_path / "reduced.fits").read_bytes() == before
    write(e.replace(data=np.zeros((4, 4))), "reduced.fits", overwrite=True)
    assert (tmp_path / "reduced.fits").read_bytes() != before


def test_a_write_an_interrupt_cut_short_before_its_exit_is_removed(tmp_path):
    # an interrupt raised as __exit__ is entered skips its clean-up: the command line's
    # handler removes what is left, and only that (a finished output stays)
    done = tmp_path / "done.txt"
    with atomic_output(done) as tmp:
        tmp.write_text("whole")
    cut = atomic_output(tmp_path / "cut.txt")
    left = cut.__enter__()
    left.write_text("half")
    assert [p.name for p in tmp_path.glob(".*.tmp")] == [left.name]
    atomic_output.remove_unfinished()
    assert not list(tmp_path.glob(".*.tmp"))
    assert done.read_text() == "whole" and not (tmp_path / "cut.txt").exists()
