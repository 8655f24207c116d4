"""Moved to :mod:`omnican.command.motion`; this name stays for one release, then goes.

``import omnican.motion`` gives the very module :mod:`omnican.command.motion`
(the same objects, private names too) and a DeprecationWarning naming its new home.
"""

import importlib
import sys
import warnings

warnings.warn("omnican.motion moved to omnican.command.motion; the old name goes in the next "
              "release", DeprecationWarning, stacklevel=2)
sys.modules[__name__] = importlib.import_module("omnican.command.motion")
