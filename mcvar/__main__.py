"""``python -m mcvar``: the same as the ``mcvar`` console script."""
from .cli import main

raise SystemExit(main())
