"""``python -m goniometer.cli``: the ``gonio`` command."""

import sys

from goniometer.cli import main

sys.exit(main())
