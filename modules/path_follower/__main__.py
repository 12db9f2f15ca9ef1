"""``python -m modules.path_follower``."""

from modules.path_follower.module import PathFollowerModule

raise SystemExit(PathFollowerModule.main())
