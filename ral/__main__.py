"""``python -m ral``: the robot's RAL process (normally started by the Module Manager from the manifest)."""

from ral.module import main

raise SystemExit(main())
