"""Moved to :mod:`omnican.protocol.slamware`; this name stays for one release, then goes.

``import omnican.slamware`` (or ``from omnican import slamware``) gives the very module
:mod:`omnican.protocol.slamware` (the same objects, private names too) and a
DeprecationWarning naming its new home.
"""

import importlib
import sys
import warnings

warnings.warn("omnican.slamware moved to omnican.protocol.slamware; the old name goes in the "
              "next release", DeprecationWarning, stacklevel=2)
sys.modules[__name__] = importlib.import_module("omnican.protocol.slamware")
