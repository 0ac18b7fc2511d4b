"""``python -m lupin`` runs the same command line as the ``lupin`` script."""

from lupin.cli import main

raise SystemExit(main())
