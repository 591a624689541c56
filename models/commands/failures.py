"""How the models' commands end when some models failed (``docs/models.md`` §3, "A model that
fails"): the results of the models that worked are printed first, then one line per failed model on
stderr, and the command exits with :data:`EXIT_MODEL_FAILED`."""

from __future__ import annotations

import sys
from typing import Mapping

#: exit status of a command that printed the other models' results and one line per failed model:
#: not 0, so that a script notices; not 2, which means the input was refused and nothing computed
EXIT_MODEL_FAILED = 1


def report_failures(failed: Mapping[str, str]) -> int:
    """Print ``failed {name}: {why}`` on stderr for each failed model; the exit status: 0 when none
    failed, :data:`EXIT_MODEL_FAILED` otherwise."""
    for name, why in failed.items():
        print(f"failed {name}: {why}", file=sys.stderr)
    return EXIT_MODEL_FAILED if failed else 0
