"""A block's export as a folder: InView's per-test CSVs, one file per test, in ``<run>-<block>-export/``.

The inbox treats such a folder as one export file: its size and time are its files' together (it is stable
when no file in it changes), its SHA-256 covers every file's name and bytes in natural order, and it is
archived and taken out of the inbox whole.
"""

from __future__ import annotations

import hashlib
import shutil
from pathlib import Path

from drivers.kla.export import export_files, natural_key


def _files(path: Path) -> list[Path]:
    return sorted((f for f in path.iterdir() if f.is_file()), key=natural_key)


def tree_stat(path: Path) -> tuple[int, int]:
    """(size, newest mtime_ns) of a file, or of a folder's files together with their count."""
    if not path.is_dir():
        st = path.stat()
        return st.st_size, st.st_mtime_ns
    files = _files(path)
    stats = [f.stat() for f in files]
    size = sum(s.st_size for s in stats) if all(s.st_size > 0 for s in stats) else 0  # a 0-byte file: not yet
    return size + len(files), max([path.stat().st_mtime_ns, *(s.st_mtime_ns for s in stats)])


def sha256_tree(path: Path) -> str:
    """A file's SHA-256, or a folder's over its export files' names and bytes in natural order."""
    digest = hashlib.sha256()
    for f in export_files([path]) if path.is_dir() else [path]:
        if path.is_dir():
            digest.update(f.name.encode() + b"\0")
        with f.open("rb") as fh:
            while chunk := fh.read(1 << 20):
                digest.update(chunk)
    return digest.hexdigest()


def lock_names(path: Path) -> list[str]:
    """The names Excel's '~$' lock files would cut: the file's, or each file's in the folder."""
    return [f.name for f in _files(path)] if path.is_dir() else [path.name]


def copy_export(src: Path, dst: Path) -> None:
    if src.is_dir():
        shutil.copytree(src, dst, dirs_exist_ok=True)
    else:
        shutil.copy2(src, dst)


def remove_export(src: Path) -> None:
    if src.is_dir():
        shutil.rmtree(src, ignore_errors=True)
    else:
        src.unlink(missing_ok=True)
