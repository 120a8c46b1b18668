"""``python -m elastic_pm_dyn`` is the ``elastic-pm-dyn`` command (Ctrl-C: one line, exit 130)."""

import sys

from elastic_pm_dyn.entry import cli

sys.exit(cli())
