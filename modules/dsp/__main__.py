"""``python -m modules.dsp``: the DSP process (modules/dsp/process.py)."""

import sys

from modules.dsp.process import DspModule

sys.exit(DspModule.main())
