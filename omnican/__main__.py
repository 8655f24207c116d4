import sys

from omnican.cli import main

sys.exit(main())
