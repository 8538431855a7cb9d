"""The one atomic writer (stores, form-factor files, images, bench reports) and the parent-folder check."""

import os

import pytest

from pydynrad.atomic import TMP_MARK, check_parent_folder, write_atomic
from pydynrad.errors import InvalidInputError


def test_bytes_and_writer_functions_land_whole(tmp_path):
    target = tmp_path / "a.bin"
    assert write_atomic(target, b"first") == target
    assert target.read_bytes() == b"first"
    seen = []

    def writer(tmp):
        seen.append(tmp)
        assert tmp.parent == target.parent and TMP_MARK in tmp.name  # same folder: the rename is atomic
        tmp.write_bytes(b"second")

    write_atomic(target, writer)
    assert target.read_bytes() == b"second" and not seen[0].exists()
    assert sorted(os.listdir(tmp_path)) == ["a.bin"]


def test_a_failed_write_keeps_the_old_file_and_leaves_no_debris(tmp_path):
    target = tmp_path / "a.bin"
    target.write_bytes(b"old")

    def fails(tmp):
        tmp.write_bytes(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        write_atomic(target, fails)
    assert target.read_bytes() == b"old"
    assert sorted(os.listdir(tmp_path)) == ["a.bin"]


def test_a_missing_folder_is_named(tmp_path):
    missing = tmp_path / "nope" / "a.bin"
    for call in (lambda: check_parent_folder(missing), lambda: write_atomic(missing, b"x")):
        with pytest.raises(InvalidInputError, match="the folder .*nope.* does not exist"):
            call()
    assert check_parent_folder(tmp_path / "ok.bin") == tmp_path / "ok.bin"
