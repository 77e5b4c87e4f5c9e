"""Who may command a run: decided by the OS's ownership and permission bits of the journal, never by a row.

A command is a row that the sender writes into the journal, so the sender writes its own user id too and
could write any. What it cannot forge is who the kernel lets write the file: the journal and its SQLite
side files are created ``0640`` (owner writes, the journal's group reads, nobody else opens it), and the
engine trusts its command rows only while that still holds. See docs/security.md.
"""

from __future__ import annotations

import grp
import os
import pwd
import stat
from pathlib import Path

from core.errors import InputError

JOURNAL_MODE = 0o640  # owner reads and writes; the journal's group watches; others cannot open it
SIDE_SUFFIXES = (
    "-wal",
    "-shm",
)  # SQLite's write-ahead log and shared memory: writing them is writing the journal


def journal_gid(group: str | None, source: str = "run.group") -> int | None:
    """The gid of the group that may watch a run (None: the owner's own group); refused when unusable."""
    if group is None or not group.strip():
        return None
    try:
        entry = grp.getgrnam(group.strip())
    except KeyError:
        raise InputError(source, f"no such group {group!r} on this machine") from None
    uid = os.getuid()
    if uid != 0:
        me = pwd.getpwuid(uid).pw_name
        if entry.gr_gid != os.getgid() and me not in entry.gr_mem and entry.gr_gid not in os.getgroups():
            raise InputError(
                source, f"{me} is not a member of group {group!r}, so cannot give a journal to it"
            )
    return entry.gr_gid


def protect(path: str | Path, gid: int | None = None) -> None:
    """Give a journal file (or a side file) the journal's mode and, when asked, its group."""
    p = Path(path)
    if gid is not None:
        os.chown(p, -1, gid)
    os.chmod(p, JOURNAL_MODE)


def protect_side_files(journal: str | Path) -> None:
    """The -wal and -shm files get the journal's own group and mode (SQLite copies only the mode)."""
    p = Path(journal)
    gid = p.stat().st_gid
    for suffix in SIDE_SUFFIXES:
        side = Path(str(p) + suffix)
        if side.exists() and (side.stat().st_gid != gid or stat.S_IMODE(side.stat().st_mode) != JOURNAL_MODE):
            protect(side, gid)


def command_channel_problem(journal: str | Path, owner_uid: int) -> str:
    """Why the journal's command rows cannot be trusted right now, or "" when only its owner can write it.

    Each of the journal and its side files must be owned by the run's owner and carry no group or
    other write bit: then every row in it was written by the owner's processes (or root's).
    """
    p = Path(journal)
    for f in (p, *(Path(str(p) + s) for s in SIDE_SUFFIXES)):
        try:
            st = f.stat()
        except FileNotFoundError:
            continue
        mode = stat.S_IMODE(st.st_mode)
        if st.st_uid != owner_uid:
            return f"{f.name} is owned by uid {st.st_uid}, not the run's owner: commands are not trusted"
        if mode & (stat.S_IWGRP | stat.S_IWOTH):
            who = "its group" if mode & stat.S_IWGRP and not mode & stat.S_IWOTH else "others"
            return (
                f"{f.name} is writable by {who} (mode {mode:04o}): commands are not trusted; "
                f"chmod {JOURNAL_MODE:o} it"
            )
    return ""


def user_name(uid: int) -> str:
    """The login name of a uid (the uid itself when the machine has no entry for it)."""
    try:
        return pwd.getpwuid(uid).pw_name
    except KeyError:
        return str(uid)
