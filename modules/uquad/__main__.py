import sys

from modules.uquad.module import main

sys.exit(main())
