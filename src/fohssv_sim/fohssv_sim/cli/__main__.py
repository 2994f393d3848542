"""``python -m fohssv_sim.cli``: the ``fohssv`` command."""

import sys

from . import main

sys.exit(main())
