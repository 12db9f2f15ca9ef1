"""``python -m modules.vision``: run the vision module process."""

from modules.vision.process import Vision

if __name__ == "__main__":
    raise SystemExit(Vision.main())
