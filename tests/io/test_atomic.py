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
