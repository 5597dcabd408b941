import sys

from sim_hil.entry import main

sys.exit(main())
