import sys

from ground_station.entry import main

sys.exit(main())
