"""``python -m modules.lidar_logger``: the lidar logger as a bus module (see ``module.py``)."""

from modules.lidar_logger.module import LidarLoggerModule

raise SystemExit(LidarLoggerModule.main())
