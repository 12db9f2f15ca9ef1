"""``python -m modules.vision``: run the vision module process."""

# the vision parts (numpy, the pipeline, the simulated camera) are imported here, ahead, where a standby interpreter
# preloads them (module_manager/standby.py), and not at the top of module.py, which the Module Manager imports to
# check a manifest
import modules.vision.pipeline  # noqa: F401
import modules.vision.sim_camera  # noqa: F401
from modules.vision.module import Vision

if __name__ == "__main__":
    raise SystemExit(Vision.main())
