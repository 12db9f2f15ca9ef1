"""``python -m modules.dsp``: the DSP process (modules/dsp/module.py)."""

import sys

from modules.dsp.module import DspModule

sys.exit(DspModule.main())
