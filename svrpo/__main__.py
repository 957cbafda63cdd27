"""`python -m svrpo`: the `svrpo` command."""

from svrpo.cli import main

raise SystemExit(main())
