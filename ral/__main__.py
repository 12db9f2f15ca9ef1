"""``python -m ral``: the robot's RAL process (normally started by the Module Manager from the manifest)."""

from ral.process import main

raise SystemExit(main())
