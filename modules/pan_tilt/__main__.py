"""``python -m modules.pan_tilt``."""

from modules.pan_tilt.module import PanTiltModule

raise SystemExit(PanTiltModule.main())
