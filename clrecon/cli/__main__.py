"""``python -m clrecon.cli``: the ``clrecon`` command."""
import sys

from clrecon.cli import main

sys.exit(main())
