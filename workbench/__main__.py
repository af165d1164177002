import sys

from .cli import main

# guarded: the H-infinity synthesis runs in a spawned process, which re-imports __main__
if __name__ == "__main__":
    sys.exit(main())
