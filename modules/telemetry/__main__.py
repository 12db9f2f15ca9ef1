"""``python -m modules.telemetry``."""

from modules.telemetry.module import TelemetryModule

raise SystemExit(TelemetryModule.main())
