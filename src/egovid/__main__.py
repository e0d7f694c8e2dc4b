"""``python -m egovid`` = the ``egovid`` command."""

from egovid.cli import main

main()
