"""``python -m modules.dsp.sim``: see modules/dsp/sim/cli.py."""

import sys

from modules.dsp.sim.cli import main

sys.exit(main())
