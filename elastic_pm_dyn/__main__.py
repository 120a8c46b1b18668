"""``python -m elastic_pm_dyn`` is the ``elastic-pm-dyn`` command."""

import sys

from elastic_pm_dyn.cli import main

sys.exit(main())
