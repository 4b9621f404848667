"""``python -m lanecast``: the same as the ``lanecast`` command."""

import sys

from lanecast.workflows.cli import main

sys.exit(main())
