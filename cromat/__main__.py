from cromat.cli import main

raise SystemExit(main())
