"""``python -m modules.trajectory``: the trajectory generator as a bus module (see ``module.py``)."""

from modules.trajectory.module import TrajectoryModule

raise SystemExit(TrajectoryModule.main())
