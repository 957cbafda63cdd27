"""`python -m svrpo.cli`: the `svrpo` command."""

from svrpo.cli import main

raise SystemExit(main())
