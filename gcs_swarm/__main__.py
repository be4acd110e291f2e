"""``python -m gcs_swarm``: the same as the ``gcs-swarm`` console script."""

from gcs_swarm.cli import main

raise SystemExit(main())
