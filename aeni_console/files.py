"""Files the application writes and reads: atomic writes, output folders, and OS errors as one line.

Shared by the CLI, the reports and the bench; the checks turn what the OS would say with a traceback (a folder
where a file is expected, a file in the way, permission denied) into one line naming the path.
"""

from __future__ import annotations

import errno
import os
import tempfile
from pathlib import Path

from core.errors import InputError


def write_atomic(path: str | Path, text: str) -> None:
    """Write to a temporary file beside the target, then rename: never half-written."""
    target = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=f".{target.name}.", dir=target.parent or ".")
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; the file gets the mode any new file would
        os.replace(tmp, target)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


_ERRNO_TEXT = {
    errno.EACCES: "permission denied",
    errno.EPERM: "operation not permitted",
    errno.ENOENT: "no such file or folder",
    errno.EEXIST: "already exists",
    errno.ENOTDIR: "a file is in the way (a folder was expected)",
    errno.EISDIR: "is a folder, not a file",
    errno.EROFS: "read-only file system",
    errno.ENOSPC: "no space left on the device",
}


def os_error_line(exc: OSError) -> str:
    """``path: what is wrong`` for an OS error, in the CLI's one-line style."""
    what = _ERRNO_TEXT.get(exc.errno or 0) or (exc.strerror or str(exc)).lower()
    if exc.filename is not None:
        return f"{exc.filename}: {what}"
    return str(exc) if not exc.strerror else what


def input_file(path: str | Path, what: str = "file") -> Path:
    """An existing, readable regular file, or InputError saying which of those it is not."""
    p = Path(path)
    if p.is_dir():
        raise InputError(str(p), f"is a folder, not a {what}")
    if not p.exists():
        raise InputError(str(p), f"no such {what}")
    if not p.is_file():
        raise InputError(str(p), f"is not a regular file (a {what} was expected)")
    if not os.access(p, os.R_OK):
        raise InputError(str(p), f"cannot read the {what}: permission denied")
    return p


def make_folder(path: str | Path, what: str = "folder") -> Path:
    """Create a folder (and its parents) or say, naming it, why it cannot be created."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(str(p), f"is a file; the {what} must be a folder")
    blocker = next((a for a in (p, *p.parents) if a.exists() and not a.is_dir()), None)
    if blocker is not None:
        raise InputError(str(p), f"cannot create the {what}: {blocker} is a file")
    try:
        p.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(str(p), f"cannot create the {what}: {os_error_line(exc)}") from None
    if not os.access(p, os.W_OK | os.X_OK):
        raise InputError(str(p), f"cannot write in the {what}: permission denied")
    return p


def check_out_folder(path: str | Path) -> Path:
    """An output folder (``--out``): created when missing, refused when a file is already there."""
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise InputError(str(p), "is a file; --out takes a folder (it is created when missing)")
    return make_folder(p, "output folder")


def write_new_file(path: str | Path, text: str, *, force: bool = False) -> Path:
    """A template written whole or not at all; an existing file only replaced when asked (``--force``)."""
    p = Path(path)
    if p.exists() and not force:
        raise InputError(str(p), "already exists (use --force to overwrite it)")
    tmp = p.with_name(f".{p.name}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, p)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise InputError(str(p), f"cannot write ({exc.strerror or exc})") from None
    return p
