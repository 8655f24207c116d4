"""Names a package gives from its modules, each imported when first asked for (PEP 562):
a package whose modules pull in heavy dependencies or layers above stays cheap to import
for who names only part of it.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, MutableMapping
from typing import Any


def lazy_names(package: str, homes: Mapping[str, str],
               namespace: MutableMapping[str, Any]) -> Callable[[str], Any]:
    """The module ``__getattr__`` of ``package`` that gives each name of ``homes`` (name
    -> its module, relative to ``package``) from that module when first asked for, and
    keeps it in ``namespace`` (the package's ``globals()``) so the next look finds it
    there. Any other name raises AttributeError, as a module's would."""
    def module_getattr(name: str) -> Any:
        home = homes.get(name)
        if home is None:
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        value = getattr(importlib.import_module(f"{package}.{home}"), name)
        namespace[name] = value
        return value

    return module_getattr
