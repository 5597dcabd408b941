import sys

from sim_hil.cli import main

sys.exit(main())
