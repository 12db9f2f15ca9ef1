"""``python -m modules.path_follower``."""

# mode 3's follower (numpy) is imported here, ahead, where a standby interpreter preloads it
# (module_manager/standby.py), and not at the top of module.py, which the Module Manager imports to check a manifest
import modules.path_follower.onboard  # noqa: F401
from modules.path_follower.module import PathFollowerModule

raise SystemExit(PathFollowerModule.main())
