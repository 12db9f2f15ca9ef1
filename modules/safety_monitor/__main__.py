"""``python -m modules.safety_monitor``."""

from modules.safety_monitor.module import SafetyMonitorModule

raise SystemExit(SafetyMonitorModule.main())
