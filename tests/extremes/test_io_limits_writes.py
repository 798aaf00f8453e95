"""Safe writes of clrecon.io: every file the library writes appears atomically (a temporary
file in the same folder, then ``os.replace``); a failure at any step leaves the old file, or
TLFR pair, as it was and no temporary file behind."""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import pytest
from io_cases import small_buffer

import clrecon.io.exr
import clrecon.io.image
import clrecon.io.tlfr
from clrecon.io import load_samples, save_image, save_samples


# ------------------------------------------------------------------------------------------
# safe writes: temp file in the same folder, then os.replace
# ------------------------------------------------------------------------------------------
def listing(folder: Path) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir()) if p.is_file()}


SAMPLE_FILES = {".bin": ["f.bin", "f.bin.header"], ".txt": ["f.txt", "f.txt.header"],
                ".exr": ["f.exr"], ".npz": ["f.npz"]}


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_save_samples_leaves_only_its_files(tmp_path, ext):
    save_samples(tmp_path / f"f{ext}", small_buffer())
    assert sorted(listing(tmp_path)) == SAMPLE_FILES[ext]
    umask = os.umask(0)
    os.umask(umask)
    for name in SAMPLE_FILES[ext]:
        assert (tmp_path / name).stat().st_mode & 0o777 == 0o666 & ~umask


def fail_last_rename(monkeypatch, renames: int) -> None:
    """Make the ``renames``-th os.replace from now on (the last of a save) fail."""
    real = os.replace
    calls = []

    def replace(src, dst):
        calls.append(dst)
        if len(calls) == renames:
            raise OSError(28, "injected: no space left")
        return real(src, dst)
    monkeypatch.setattr(os, "replace", replace)


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_failed_rename_keeps_the_old_files(tmp_path, ext, monkeypatch):
    """For a TLFR pair the header's rename fails after the data's: the data is restored
    (or, where there was none, removed)."""
    fail_last_rename(monkeypatch, len(SAMPLE_FILES[ext]))
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    assert listing(tmp_path) == {}
    monkeypatch.undo()
    save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    before = listing(tmp_path)
    fail_last_rename(monkeypatch, len(SAMPLE_FILES[ext]))
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=2))
    monkeypatch.undo()
    assert listing(tmp_path) == before
    assert load_samples(tmp_path / f"f{ext}").shape == small_buffer().shape


def test_tlfr_pair_restored_without_hard_links(tmp_path, monkeypatch):
    """Where hard links fail, the old data file is moved aside and moved back."""
    path = tmp_path / "f.bin"
    save_samples(path, small_buffer(seed=1))
    before = listing(tmp_path)

    def no_link(src, dst):
        raise OSError(1, "links not supported")
    monkeypatch.setattr(os, "link", no_link)
    fail_last_rename(monkeypatch, 3)  # the move aside, the data, then the header
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    monkeypatch.undo()
    assert listing(tmp_path) == before


def inject_write_failure(monkeypatch, ext: str) -> None:
    """Make the next save of ``ext`` fail half-way through writing its data."""
    def boom():
        raise OSError(5, "injected: write failed")

    if ext == ".exr":
        real = clrecon.io.exr.oiio_write

        def partial(path, *args):
            real(path, *args)
            Path(path).write_bytes(Path(path).read_bytes()[:100])
            boom()
        monkeypatch.setattr(clrecon.io.exr, "oiio_write", partial)
    elif ext == ".npz":
        real_savez = np.savez

        def savez(f, **arrays):
            real_savez(f, **arrays)
            boom()
        monkeypatch.setattr(np, "savez", savez)
    else:
        real_data = clrecon.io.tlfr._write_tlfr_data

        def data(f, records, encoding):
            real_data(f, records[: len(records) // 2], encoding)
            boom()
        monkeypatch.setattr(clrecon.io.tlfr, "_write_tlfr_data", data)


@pytest.mark.parametrize("ext", list(SAMPLE_FILES))
def test_failed_write_leaves_nothing_new(tmp_path, ext, monkeypatch):
    """A failure in the middle of writing the data: no temp left, no file created, an
    existing file (pair) untouched."""
    inject_write_failure(monkeypatch, ext)
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer())
    assert listing(tmp_path) == {}
    monkeypatch.undo()
    save_samples(tmp_path / f"f{ext}", small_buffer(seed=1))
    before = listing(tmp_path)
    inject_write_failure(monkeypatch, ext)
    with pytest.raises(OSError, match="injected"):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=2))
    assert listing(tmp_path) == before


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_header_path_is_a_directory(tmp_path, ext):
    (tmp_path / f"f{ext}.header").mkdir()
    with pytest.raises(OSError, match=rf"f\{ext}\.header"):
        save_samples(tmp_path / f"f{ext}", small_buffer())
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"f{ext}.header"]


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_header_write_fails_pair_intact(tmp_path, ext, monkeypatch):
    path = tmp_path / f"f{ext}"
    save_samples(path, small_buffer(seed=1))
    before = listing(tmp_path)

    def header(*args, **kwargs):
        raise OSError(13, "injected: header not writable")
    monkeypatch.setattr(clrecon.io.tlfr, "tlfr_header_text", header)
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    assert listing(tmp_path) == before
    (tmp_path / f"f{ext}").unlink()
    (tmp_path / f"f{ext}.header").unlink()
    with pytest.raises(OSError, match="injected"):
        save_samples(path, small_buffer(seed=2))
    assert listing(tmp_path) == {}


@pytest.mark.parametrize("ext", [".bin", ".txt"])
def test_tlfr_data_path_is_a_directory(tmp_path, ext):
    """The data rename is refused before the header is replaced: the old header stays."""
    save_samples(tmp_path / "g.bin", small_buffer())
    os.replace(tmp_path / "g.bin.header", tmp_path / f"f{ext}.header")
    (tmp_path / "g.bin").unlink()
    (tmp_path / f"f{ext}").mkdir()
    before = listing(tmp_path)
    with pytest.raises(OSError):
        save_samples(tmp_path / f"f{ext}", small_buffer(seed=3))
    assert listing(tmp_path) == before


@pytest.mark.parametrize("ext", [".exr", ".png"])
def test_save_image_atomic(tmp_path, ext, monkeypatch):
    path = tmp_path / f"img{ext}"
    save_image(path, np.full((3, 4, 3), 0.25, np.float32))
    assert sorted(listing(tmp_path)) == [f"img{ext}"]
    before = listing(tmp_path)

    def replace(src, dst):
        raise OSError(28, "injected: no space left")
    monkeypatch.setattr(os, "replace", replace)
    with pytest.raises(OSError, match="injected"):
        save_image(path, np.full((3, 4, 3), 0.75, np.float32))
    assert listing(tmp_path) == before
    monkeypatch.undo()
    real = clrecon.io.image.oiio_write

    def partial(p, *args):
        real(p, *args)
        raise OSError(5, "injected: write failed")
    monkeypatch.setattr(clrecon.io.image, "oiio_write", partial)
    with pytest.raises(OSError, match="injected"):
        save_image(tmp_path / f"new{ext}", np.zeros((3, 4, 3), np.float32))
    assert listing(tmp_path) == before


def test_save_over_a_read_only_file_replaces_it(tmp_path):
    """Replacing, not rewriting in place: a read-only old file is no obstacle, and a reader
    holding the old file keeps reading the old bytes."""
    path = tmp_path / "f.npz"
    save_samples(path, small_buffer(seed=1))
    old = path.read_bytes()
    path.chmod(0o444)
    with open(path, "rb") as reader:
        save_samples(path, small_buffer(seed=2))
        assert reader.read() == old
