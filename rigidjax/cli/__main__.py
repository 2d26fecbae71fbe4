"""`python -m rigidjax.cli`: the `rigidjax` command."""

from .main import main

raise SystemExit(main())
