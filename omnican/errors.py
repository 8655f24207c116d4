"""Exceptions raised by omnican.

Every error a user can cause (bad config, bad EDS, bad command) is a subclass of
:class:`ConfigError` or :class:`ValueError` with a message that names the problem,
so the CLI can print it as one line.
"""

from __future__ import annotations


class OmnicanError(Exception):
    """Base class of omnican's run-time errors."""


class ConfigError(OmnicanError, ValueError):
    """A configuration, geometry or EDS problem; the message names the key and the problem."""


class DriveError(OmnicanError):
    """A drive did not do what it was asked (SDO abort, timeout, refused transition, fault)."""


class BusError(OmnicanError):
    """The CAN bus could not be opened or went down."""


class GamepadError(OmnicanError):
    """No usable gamepad."""


class RecordingError(ConfigError):
    """A recording that cannot be read: missing, unreadable, unknown format, empty."""


class BaseStoppedError(OmnicanError):
    """The base stopped itself (a fault, a lost drive) during the motion."""


#: How much of a value an error message quotes (a client may send a megabyte).
QUOTE_LIMIT = 40


def quote(value: object, limit: int = QUOTE_LIMIT) -> str:
    """``repr(value)`` for an error message, at most ``limit`` characters of it: a longer
    one is cut and says how long it was, so a megabyte from a client is not echoed to the
    log, a status message or a service's answer. The repr of a long container is never
    built whole (only its first items)."""
    if isinstance(value, (str, bytes, bytearray)):
        text = _cut_repr(value, limit + 1)
        size = len(value)
        unit = "characters" if isinstance(value, str) else "bytes"
    elif isinstance(value, (list, tuple, dict, set, frozenset)):
        text = _container_repr(value, limit)
        size = len(value)
        unit = "item" if size == 1 else "items"
    else:
        text = repr(value)
        size, unit = len(text), "characters"
    if len(text) <= limit:
        return text
    return f"{text[:limit]}... ({size} {unit})"


def _cut_repr(value: str | bytes | bytearray, n: int) -> str:
    """The repr of ``value``'s first ``n`` items, quoted as the whole value's repr is:
    Python quotes with ``"`` a value holding a ``'`` and no ``"``, which the part cut off
    may hold alone."""
    text = repr(value[:n])
    if len(value) > n:
        if isinstance(value, str):
            double = "'" in value and '"' not in value
        else:
            double = b"'" in value and b'"' not in value
        if double and not text.rstrip(")").endswith('"'):
            start = text.index("'")  # after b or bytearray(b
            end = text.rindex("'")
            text = f'{text[:start]}"{text[start + 1:end]}"{text[end + 1:]}'
    return text


def _container_repr(value: object, limit: int) -> str:
    """The repr of a container's first items, enough for ``limit`` characters."""
    import reprlib

    r = reprlib.Repr()
    r.maxlevel, r.maxstring, r.maxother = 2, limit, limit
    r.maxlist = r.maxtuple = r.maxdict = r.maxset = r.maxfrozenset = max(1, limit // 2)
    if not isinstance(value, dict):
        return r.repr(value)
    # reprlib sorts a dict's keys; a client's dict is quoted in the order it was sent.
    items = []
    for i, (key, item) in enumerate(value.items()):
        if i == r.maxdict:
            items.append("...")
            break
        items.append(f"{r.repr(key)}: {r.repr(item)}")
    return "{" + ", ".join(items) + "}"


def printable(text: str, limit: int | None = None) -> str:
    """``text`` from the network as it may be shown on a terminal or written to a log:
    each character that is not printable (C0 and C1 controls, DEL, format characters
    such as bidirectional overrides, line and paragraph separators, surrogates, code
    points not assigned) written as Python writes it in a string literal (``\\x1b``,
    ``\\u202e``), and a backslash doubled, so a peer's name or message can neither
    steer the terminal (clear it, set its title, hide text) nor pass an escape of its
    own as one of ours. Printable text, non-ASCII included, stays as it is. ``limit``:
    at most that many characters of ``text`` are shown, then how long it was."""
    cut = text if limit is None or len(text) <= limit else text[:limit]
    out = cut if cut.isprintable() and "\\" not in cut else "".join(map(_shown, cut))
    return out if cut is text else f"{out}... ({len(text)} characters)"


def _shown(ch: str) -> str:
    if ch == "\\":
        return "\\\\"
    if ch.isprintable():
        return ch
    code = ord(ch)
    return f"\\x{code:02x}" if code < 0x100 else f"\\u{code:04x}" if code < 0x10000 \
        else f"\\U{code:08x}"
