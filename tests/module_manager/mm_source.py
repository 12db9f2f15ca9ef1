"""``python -m mm_source``: the test source module."""

from mm_modules import Source

raise SystemExit(Source.main())
