"""Where a run's alerts go: ``[notify]`` in the run file. The URLs carry secrets (tokens, passwords), so they
may come from an owner-only file, and they are never part of the campaign config the journal stores.

Sending is the application's (aeni_console.alerts, through apprise); core only reads and checks the table.
"""

from __future__ import annotations

import difflib
import json
import logging
import os
import stat
import warnings
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from core.errors import InputError

DEFAULT_INSTRUMENT_SILENCE_S = 1800.0
DEFAULT_REPEAT_S = 900.0


@dataclass(frozen=True)
class NotifyConfig:
    """Alert URLs (apprise's: mailto://, slack://, msteams://, matrix://, ntfy://, json:// ...) and when."""

    urls: tuple[str, ...] = ()
    instrument_silence_s: float = (
        DEFAULT_INSTRUMENT_SILENCE_S  # alert when the instrument says nothing this long
    )
    repeat_s: float = DEFAULT_REPEAT_S  # the same kind of alert at most once per this

    @property
    def enabled(self) -> bool:
        return bool(self.urls)

    def to_json(self) -> str:
        return json.dumps(asdict(self))

    @classmethod
    def from_mapping(cls, data: Mapping[str, Any], source: str) -> NotifyConfig:
        try:
            return cls(
                urls=tuple(str(u) for u in data.get("urls", ())),
                instrument_silence_s=float(data.get("instrument_silence_s", DEFAULT_INSTRUMENT_SILENCE_S)),
                repeat_s=float(data.get("repeat_s", DEFAULT_REPEAT_S)),
            )
        except (TypeError, ValueError) as exc:
            raise InputError(source, f"not a notify config ({exc})") from None


def read_urls_file(path: str | Path) -> tuple[str, ...]:
    """One URL a line (blank lines and # comments skipped), from a file only its owner may read."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise InputError(str(p), "no such file (notify.urls_file)") from None
    except OSError as exc:
        raise InputError(str(p), f"cannot read notify.urls_file ({exc.strerror or exc})") from None
    if not stat.S_ISREG(st.st_mode):
        raise InputError(str(p), "notify.urls_file is not a file")
    if st.st_mode & 0o077:
        raise InputError(
            str(p),
            f"notify.urls_file is readable by others (mode {stat.S_IMODE(st.st_mode):04o}); alert URLs carry "
            "secrets: chmod 600 it",
        )
    if st.st_uid != os.getuid():
        raise InputError(str(p), "notify.urls_file belongs to another user")
    try:
        text = p.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(str(p), f"cannot read notify.urls_file ({exc})") from None
    return tuple(ln.strip() for ln in text.splitlines() if ln.strip() and not ln.strip().startswith("#"))


def import_apprise() -> Any:
    """apprise, imported without its DeprecationWarning (the stdlib's imghdr), which would be a second line
    under a one-line error and noise in an engine's log. Its plugins load lazily: wrap their first use too."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        import apprise
    return apprise


def check_alert_url(url: str, field: str) -> None:
    """Refuse at start a URL apprise cannot send to (a typo in the scheme would lose every alert of the run).

    apprise itself decides (``Apprise().add``), so every scheme it knows is accepted and nothing else; the
    message names the scheme, never the URL (it may hold a token)."""
    apprise = import_apprise()
    from apprise.manager_plugins import NotificationManager

    scheme, sep, _ = url.partition("://")
    if not sep or not scheme:
        # the URL itself is not repeated: it may hold a token
        raise InputError(field, "an entry is not a URL (expected SCHEME://...; see apprise's list)")
    log = logging.getLogger("apprise")
    level = log.level
    log.setLevel(logging.CRITICAL + 1)  # apprise's own words could name the host or the token
    try:
        with warnings.catch_warnings():  # its plugins load here, one with the stdlib's deprecated imghdr
            warnings.simplefilter("ignore", DeprecationWarning)
            if apprise.Apprise().add(url):
                return
            known = sorted(NotificationManager().schemas())
    finally:
        log.setLevel(level)
    low = scheme.lower()
    if low not in known:
        near = difflib.get_close_matches(low, known, n=1)
        hint = f" (did you mean {near[0]}://?)" if near else ""
        raise InputError(
            field, f"scheme {scheme}:// is not one apprise knows{hint}: no alert of the run could be sent"
        )
    raise InputError(
        field,
        f"apprise cannot use this {low}:// URL (a host, user or token missing?); see apprise's page for {low}://",
    )


def make_notify_config(
    urls: Sequence[str],
    urls_file: str | None,
    instrument_silence_s: float,
    repeat_s: float,
    base_dir: Path | None = None,
) -> NotifyConfig:
    found = list(urls)
    if urls_file is not None:
        file = Path(urls_file)
        if base_dir is not None and not file.is_absolute():
            file = base_dir / file
        found += read_urls_file(file)
    for k, u in enumerate(found):
        check_alert_url(
            u, f"notify.urls[{k}]" if k < len(urls) else f"notify.urls_file, URL {k - len(urls) + 1}"
        )
    return NotifyConfig(tuple(found), float(instrument_silence_s), float(repeat_s))


def write_private(path: Path, text: str) -> None:
    """A file only its owner may read or write, written without a moment of wider permissions."""
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    try:
        os.fchmod(fd, 0o600)
        os.write(fd, text.encode("utf-8"))
    finally:
        os.close(fd)


def notify_path_for(journal: str | Path) -> Path:
    """Beside the journal, owner-only: where a resumed engine finds the run's alert URLs."""
    p = Path(journal)
    return p.with_name(p.name + ".notify.json")


def load_run_notify(journal: str | Path) -> NotifyConfig:
    """A run's alert config (none when the run has none); the file must still be owner-only."""
    p = notify_path_for(journal)
    if not p.exists():
        return NotifyConfig()
    st = p.stat()
    if st.st_mode & 0o077:
        raise InputError(str(p), f"is readable by others (mode {stat.S_IMODE(st.st_mode):04o}): chmod 600 it")
    try:
        data = json.loads(p.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise InputError(str(p), f"unreadable notify config ({exc})") from None
    return NotifyConfig.from_mapping(data, str(p))
