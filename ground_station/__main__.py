import sys

from ground_station.cli import main

sys.exit(main())
