"""Moved to :mod:`omnican.command.teleop`; this name stays for one release, then goes.

``import omnican.teleop_model`` gives the very module :mod:`omnican.command.teleop`
(the same objects, private names too) and a DeprecationWarning naming its new home.
"""

import importlib
import sys
import warnings

warnings.warn("omnican.teleop_model moved to omnican.command.teleop; the old name goes in the next "
              "release", DeprecationWarning, stacklevel=2)
sys.modules[__name__] = importlib.import_module("omnican.command.teleop")
