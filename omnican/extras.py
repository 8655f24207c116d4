"""The optional extras (``pip install 'omnican[plot]'`` and the like): which modules each
one brings, whether they are installed, and how to install a missing one, worded for
the way this omnican was installed (from PyPI, or from a clone: ``pip install '.[plot]'``).

Every front end says it the same way; nothing here imports an extra."""

from __future__ import annotations

import functools
import importlib.util
import json
import os
from pathlib import Path
from urllib.parse import unquote, urlparse

#: Extra -> the top-level modules it installs (what omnican imports from it).
EXTRAS: dict[str, tuple[str, ...]] = {
    "plot": ("matplotlib",),
    "ros2": ("cyclonedds",),
    "foxglove": ("foxglove", "rosbags"),
    "mcap": ("mcap", "rosbags"),
    "gamepad": ("evdev",),
    "zenoh": ("zenoh", "rosbags"),
    "zenoh-security": ("zenoh", "rosbags", "cryptography"),
}


def missing(extra: str) -> str | None:
    """The first module of ``extra`` that is not installed, or None."""
    for module in EXTRAS[extra]:
        try:
            found = importlib.util.find_spec(module) is not None
        except ValueError:  # in sys.modules as None: an import of it fails
            found = False
        if not found:
            return module
    return None


def extra_of(module: str) -> str | None:
    """The extra that installs ``module`` (a top-level or dotted name), if any."""
    top = module.split(".", maxsplit=1)[0]
    return next((extra for extra, mods in EXTRAS.items() if top in mods), None)


@functools.lru_cache(maxsize=1)
def _source() -> tuple[str, bool] | None:
    """(directory, editable) when this omnican comes from a local directory (a clone),
    else None: the package sits in a source tree (an editable install, or PYTHONPATH),
    or pip recorded the directory it was installed from (``pip install .``)."""
    tree = Path(__file__).resolve().parents[1]
    if (tree / "pyproject.toml").is_file() and (tree / "omnican").is_dir():
        return str(tree), True
    import importlib.metadata  # only here: it costs more than the rest of startup

    for dist in importlib.metadata.distributions(name="omnican"):
        text = dist.read_text("direct_url.json")
        if not text:
            continue
        try:
            info = json.loads(text)
        except ValueError:
            continue
        url = urlparse(str(info.get("url", "")))
        if url.scheme == "file" and "dir_info" in info:
            return unquote(url.path), bool(info["dir_info"].get("editable"))
    return None


def install_hint(extra: str) -> str:
    """The command that installs ``extra``: ``pip install 'omnican[plot]'``, or from a
    clone ``pip install '.[plot]'`` (``-e`` when it was installed editable)."""
    source = _source()
    if source is None:
        return f"pip install 'omnican[{extra}]'"
    where, editable = source
    try:
        here = Path(where).resolve() == Path(os.getcwd()).resolve()
    except OSError:
        here = False
    target = "." if here else where
    return f"pip install {'-e ' if editable else ''}'{target}[{extra}]'"


def needs(extra: str, what: str) -> str | None:
    """``"<what> needs <module>: <install hint>"`` when ``extra`` is not installed, else
    None."""
    module = missing(extra)
    if module is None:
        return None
    return f"{what} needs {module}: {install_hint(extra)}"
