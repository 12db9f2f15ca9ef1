"""``python -m mm_sink``: the test sink module (class imported so its struct names read ``mm_modules:...``)."""

from mm_modules import Sink

raise SystemExit(Sink.main())
