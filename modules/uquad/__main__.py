import sys

from modules.uquad.flight_module import main

sys.exit(main())
