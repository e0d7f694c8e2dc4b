"""``python -m egovid`` = the ``egovid`` command."""

from egovid.cli import main

if __name__ == "__main__":  # worker processes (spawned) import this module without running it
    main()
